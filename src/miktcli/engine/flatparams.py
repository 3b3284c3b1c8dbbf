"""Puts all trainable parameters (and their gradients) into one contiguous buffer, so that Adam and the
gradient-norm clip are a handful of ops on one tensor: on networks this small, the cost per tensor, not the
arithmetic, decides the update's speed.
"""

from __future__ import annotations

import torch
from torch import nn


class FlatParameters:
    def __init__(self, params: list[nn.Parameter]):
        if not params:
            raise ValueError("no trainable parameters")
        self.params = params
        total = sum(p.numel() for p in params)
        self.flat = nn.Parameter(torch.zeros(total, dtype=params[0].dtype))
        self.flat.grad = torch.zeros(total, dtype=params[0].dtype)
        offset = 0
        for p in params:
            n = p.numel()
            self.flat.data[offset : offset + n].copy_(p.data.view(-1))
            p.data = self.flat.data[offset : offset + n].view_as(p)
            # Autograd accumulates into an existing .grad in place, so gradients land in the flat buffer.
            p.grad = self.flat.grad[offset : offset + n].view_as(p)
            offset += n

    def rebind(self, flat: torch.Tensor, grad: torch.Tensor) -> None:
        """Move the parameters and their gradients into `flat` and `grad` (e.g. one row each of buffers that
        hold several models, see miktcli.engine.together), values kept; the optimiser's parameter stays the same
        object, so its state and every view stay valid."""
        if flat.shape != self.flat.shape or grad.shape != self.flat.shape or not (flat.is_contiguous()
                                                                                and grad.is_contiguous()):
            raise ValueError(f"rebind needs contiguous buffers of shape {tuple(self.flat.shape)}")
        flat.copy_(self.flat.data)
        grad.copy_(self.flat.grad)
        self.flat.data, self.flat.grad = flat, grad
        offset = 0
        for p in self.params:
            n = p.numel()
            p.data = flat[offset : offset + n].view_as(p)
            p.grad = grad[offset : offset + n].view_as(p)
            offset += n

    def zero_grad(self) -> None:
        self.flat.grad.zero_()

    def clip_grad_norm(self, max_norm: float) -> torch.Tensor:
        norm = torch.linalg.vector_norm(self.flat.grad)
        self.flat.grad.mul_(torch.clamp(max_norm / (norm + 1e-6), max=1.0))
        return norm

    def check_views(self) -> bool:
        """True while every parameter and gradient still aliases the flat buffers."""
        flat_ptr, grad_ptr = self.flat.data.data_ptr(), self.flat.grad.data_ptr()
        size = self.flat.element_size() * self.flat.numel()
        return all(
            flat_ptr <= p.data.data_ptr() < flat_ptr + size and p.grad is not None
            and grad_ptr <= p.grad.data_ptr() < grad_ptr + size
            for p in self.params
        )
