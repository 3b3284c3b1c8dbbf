"""Small networks: MLPs that expose hidden pre-activations, and the observation normaliser as a module.

The normaliser keeps its statistics as buffers, so one safetensors file restores the exact policy.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

OBS_CLIP = 10.0
NORM_EPS = 1e-8


def update_moments(mean: np.ndarray, var: np.ndarray, count: float, batch: np.ndarray) -> float:
    """Merge a batch (rows = samples) into running mean/var in place (Chan et al.); returns the new count."""
    n = batch.shape[0]
    if n == 1:
        x = batch[0]
        total = count + 1.0
        delta = x - mean
        mean += delta / total
        var[...] = (var * count + delta * (x - mean)) / total
        return total
    batch_mean = batch.mean(axis=0)
    batch_var = batch.var(axis=0)
    total = count + n
    delta = batch_mean - mean
    mean += delta * (n / total)
    var[...] = (var * count + batch_var * n + np.square(delta) * count * n / total) / total
    return total


class ObsNormalizer(nn.Module):
    """Running mean/std of observations; normalises and clips to ±10. Float64 statistics as buffers.

    `clip` is not a buffer (state dicts stay as they were): a teacher imported without statistics saw raw
    observations, never clipped, and its card says so (TeacherCard.obs_clip None → no clip)."""

    def __init__(self, dim: int, clip: float = OBS_CLIP):
        super().__init__()
        self.clip = clip
        self.register_buffer("mean", torch.zeros(dim, dtype=torch.float64))
        self.register_buffer("var", torch.ones(dim, dtype=torch.float64))
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))
        self.frozen = False  # frozen at evaluation and inside a teacher

    def update(self, batch: np.ndarray) -> None:
        if self.frozen:
            return
        count = update_moments(self.mean.numpy(), self.var.numpy(), float(self.count), batch)
        self.count.fill_(count)

    def normalize_np(self, obs: np.ndarray) -> np.ndarray:
        """The rollout's hot path: numpy in, float32 numpy out."""
        mean, var = self.mean.numpy(), self.var.numpy()
        return np.clip((obs - mean) / np.sqrt(var + NORM_EPS), -self.clip, self.clip).astype(np.float32)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        out = (obs.double() - self.mean) / torch.sqrt(self.var + NORM_EPS)
        return out.clamp(-self.clip, self.clip).float()


def orthogonal_linear(n_in: int, n_out: int, gain: float) -> nn.Linear:
    layer = nn.Linear(n_in, n_out)
    nn.init.orthogonal_(layer.weight, gain)
    nn.init.zeros_(layer.bias)
    return layer


ACTIVATIONS = {"tanh": torch.tanh, "relu": torch.relu}  # what teachers may use; students are tanh (the paper)


class MLP(nn.Module):
    """MLP (tanh hidden layers unless told otherwise) with a linear output. `preactivations` gives z^j of every
    hidden layer (MIKT needs them)."""

    def __init__(self, n_in: int, hidden: list[int] | tuple[int, ...], n_out: int, out_gain: float,
                 activation: str = "tanh"):
        super().__init__()
        self.activation = activation
        self.act = ACTIVATIONS[activation]
        sizes = [n_in, *hidden]
        self.hidden = nn.ModuleList(
            orthogonal_linear(a, b, math.sqrt(2.0)) for a, b in zip(sizes[:-1], sizes[1:], strict=True)
        )
        self.head = orthogonal_linear(sizes[-1], n_out, out_gain)
        # Plain references for the hot paths (F.linear on them): they skip nn.Module's call overhead.
        self.layer_params = [(layer.weight, layer.bias) for layer in self.hidden]
        self.head_params = (self.head.weight, self.head.bias)

    @property
    def hidden_sizes(self) -> list[int]:
        return [layer.out_features for layer in self.hidden]

    @property
    def in_features(self) -> int:
        return self.hidden[0].in_features

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for weight, bias in self.layer_params:
            x = self.act(F.linear(x, weight, bias))
        return F.linear(x, *self.head_params)

    def preactivations(self, x: torch.Tensor) -> list[torch.Tensor]:
        zs = []
        for weight, bias in self.layer_params:
            z = F.linear(x, weight, bias)
            zs.append(z)
            x = self.act(z)
        return zs
