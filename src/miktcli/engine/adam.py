"""Adam as PyTorch's fused CPU kernel computes it, without torch.optim.

Constructing any torch.optim optimiser imports torch._dynamo (1.2-1.9 s here), which every `mikt` process paid
before its first step although the eager update never compiles anything. This class calls the same kernel that
`torch.optim.Adam(..., fused=True)` calls, with the same state (a float32 step count, exp_avg, exp_avg_sq), so
the numbers are bit for bit those of PyTorch's optimiser (tests/test_ppo.py checks this) and checkpoints keep
their keys.
"""

from __future__ import annotations

import torch


class FusedAdam:
    """Adam without weight decay or AMSGrad over a few tensors; `lr` may change between steps."""

    def __init__(self, params: list[torch.Tensor], lr: float, eps: float = 1e-8,
                 betas: tuple[float, float] = (0.9, 0.999)):
        if not params:
            raise ValueError("no parameters to optimise")
        self.params = list(params)
        self.lr, self.eps, self.betas = lr, eps, betas
        # Keyed by the parameter, as torch.optim keeps it: FlatParameters.rebind swaps a parameter's storage,
        # not the parameter, so its moments stay with it.
        self.state: dict[torch.Tensor, dict[str, torch.Tensor]] = {
            p: {"step": torch.zeros((), dtype=torch.float32), "exp_avg": torch.zeros_like(p),
                "exp_avg_sq": torch.zeros_like(p)} for p in self.params}

    @torch.no_grad()
    def step(self) -> None:
        live = [p for p in self.params if p.grad is not None]
        if not live:
            return
        steps = [self.state[p]["step"] for p in live]
        torch._foreach_add_(steps, 1)
        torch._fused_adam_([p.data for p in live], [p.grad for p in live],
                           [self.state[p]["exp_avg"] for p in live], [self.state[p]["exp_avg_sq"] for p in live],
                           [], steps, amsgrad=False, lr=self.lr, beta1=self.betas[0], beta2=self.betas[1],
                           weight_decay=0.0, eps=self.eps, maximize=False, grad_scale=None, found_inf=None)

    def zero_grad(self) -> None:
        for p in self.params:
            p.grad = None

    def state_of(self, param: torch.Tensor) -> dict[str, torch.Tensor]:
        """The step count and both moments of one parameter, as the optimiser holds them (not copies)."""
        return self.state[param]

    def load_state_of(self, param: torch.Tensor, state: dict[str, torch.Tensor]) -> None:
        """Copy a saved step count and moments in (shapes checked by the caller); dtypes follow the parameter."""
        own = self.state[param]
        own["step"] = state["step"].detach().to(torch.float32).reshape(()).clone()
        own["exp_avg"] = state["exp_avg"].detach().to(param.dtype).clone().contiguous()
        own["exp_avg_sq"] = state["exp_avg_sq"].detach().to(param.dtype).clone().contiguous()
