"""Small networks: MLPs that expose hidden pre-activations, and the observation normaliser as a module.

The normaliser keeps its statistics as buffers, so one safetensors file restores the exact policy.
"""

from __future__ import annotations

import math
from collections.abc import Callable

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

    def rollout(self, num_envs: int) -> RolloutNormalizer:
        """The rollout's per-step update and normalisation over numpy views of these buffers, without
        allocations; made afresh for each rollout, so it follows any load_state_dict before it."""
        return RolloutNormalizer(self, num_envs)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        out = (obs.double() - self.mean) / torch.sqrt(self.var + NORM_EPS)
        return out.clamp(-self.clip, self.clip).float()


class RolloutNormalizer:
    """`ObsNormalizer.update` and `normalize_np` for one batch of `num_envs` observations per step, in place
    over views of the module's buffers (which stay the one record of the statistics). Every operation is
    the one `update_moments` / `normalize_np` does, in the same order, so the numbers are bit-identical;
    only the temporaries are reused (per step 15.9 → 6.8 µs measured on Ant's 111 dims)."""

    def __init__(self, module: ObsNormalizer, num_envs: int):
        self.module = module
        self.mean, self.var, self.count_view = module.mean.numpy(), module.var.numpy(), module.count.numpy()
        dim = self.mean.shape[0]
        self.num_envs = num_envs
        self.delta, self.tmp, self.std = np.empty(dim), np.empty(dim), np.empty(dim)
        self.centred = np.empty((num_envs, dim))

    def update(self, batch: np.ndarray) -> None:
        if self.module.frozen:
            return
        if batch.shape[0] != 1:  # the batched merge (several envs) has no per-step temporaries worth saving
            self.module.update(batch)
            return
        x, mean, var, delta, tmp = batch[0], self.mean, self.var, self.delta, self.tmp
        count = float(self.count_view)
        total = count + 1.0
        np.subtract(x, mean, out=delta)
        mean += np.divide(delta, total, out=tmp)
        np.subtract(x, mean, out=tmp)
        tmp *= delta
        var *= count
        var += tmp
        var /= total
        self.count_view[...] = total

    def normalize_into(self, obs: np.ndarray, out: np.ndarray) -> None:
        """normalize_np(obs) written into `out` (float32, shape of obs)."""
        np.add(self.var, NORM_EPS, out=self.std)
        np.sqrt(self.std, out=self.std)
        centred = np.subtract(obs, self.mean, out=self.centred)
        centred /= self.std
        np.clip(centred, -OBS_CLIP, OBS_CLIP, out=centred)
        out[...] = centred


def linear(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None = None) -> torch.Tensor:
    """F.linear, and the same for weights stacked over seeds: a (S, out, in) weight with x (S, B, in) is one
    batched matmul (the seeds-together update, miktcli.engine.together). A 2-D weight is F.linear itself, so a
    single run's numbers are untouched; a frozen teacher's 2-D weight broadcasts over every seed's rows."""
    if weight.dim() == 2:
        return F.linear(x, weight, bias)
    if bias is None:
        return torch.bmm(x, weight.transpose(-1, -2))
    return torch.baddbmm(bias.unsqueeze(-2), x, weight.transpose(-1, -2))


def transposed(weight: torch.Tensor) -> torch.Tensor:
    """A weight's transpose for `affine_into`, detached: (in, out), or (S, in, out) for one stacked over seeds."""
    return weight.detach().transpose(-1, -2)


def affine_into(x: torch.Tensor, weight_t: torch.Tensor, bias: torch.Tensor | None, out: torch.Tensor) -> torch.Tensor:
    """x @ weight_t (+ bias) into `out`, for the rollout's buffers made once. 2-D everywhere is addmm (mm
    without a bias), what F.linear runs on a 2-D input, so a single run's bits; a stacked (S, in, out) weight
    with x (S, N, in) is one baddbmm (bmm) over the seeds (seeds together); a 2-D weight with stacked rows (a
    frozen teacher, shared by every seed) runs once over all S·N rows."""
    if weight_t.dim() == 3:
        if bias is None:
            return torch.bmm(x, weight_t, out=out)
        return torch.baddbmm(bias.unsqueeze(-2), x, weight_t, out=out)
    if x.dim() == 3:
        x, flat = x.reshape(-1, x.shape[-1]), out.view(-1, out.shape[-1])
    else:
        flat = out
    if bias is None:
        torch.mm(x, weight_t, out=flat)
    else:
        torch.addmm(bias, x, weight_t, out=flat)
    return out


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

    # The hot paths call `linear` on these, skipping nn.Module's call overhead. Read afresh at each call (not
    # kept as references), so that torch.func.functional_call's swapped parameters reach them: the
    # seeds-together update (miktcli.engine.together) runs every seed's loss through one module that way, with
    # each parameter stacked over the seeds.
    @property
    def layer_params(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        return [(layer.weight, layer.bias) for layer in self.hidden]

    @property
    def head_params(self) -> tuple[torch.Tensor, torch.Tensor]:
        return self.head.weight, self.head.bias

    @property
    def hidden_sizes(self) -> list[int]:
        return [layer.out_features for layer in self.hidden]

    @property
    def in_features(self) -> int:
        return self.hidden[0].in_features

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for weight, bias in self.layer_params:
            x = self.act(linear(x, weight, bias))
        return linear(x, *self.head_params)

    def rollout_forward(self, x: torch.Tensor) -> Callable[[], torch.Tensor]:
        """`forward(x)` for the rollout's fixed input tensor `x` (rows: envs), into buffers made once: the same
        kernels (addmm is what F.linear runs on a 2-D input, then the activation), so the same bits, without
        the per-call allocations (batch of one, 64-64: 19.6 → 8.6 µs measured). Call it under
        torch.inference_mode; the weights are read at each call, so it follows every optimiser step. With
        parameters stacked over seeds (functional_call, miktcli.engine.together) `x` is (S, N, in)."""
        act_ = {"tanh": torch.tanh_, "relu": torch.relu_}[self.activation]
        layers = [(transposed(w), b.detach()) for w, b in self.layer_params]
        head_w, head_b = transposed(self.head_params[0]), self.head_params[1].detach()
        rows = x.shape[:-1]  # (N,), or (S, N) with parameters stacked over seeds
        bufs = [torch.empty(*rows, w.shape[-1]) for w, _ in layers]
        out = torch.empty(*rows, head_w.shape[-1])

        def run() -> torch.Tensor:
            h = x
            for (w_t, b), buf in zip(layers, bufs, strict=True):
                act_(affine_into(h, w_t, b, buf))
                h = buf
            return affine_into(h, head_w, head_b, out)

        return run

    def preactivations(self, x: torch.Tensor) -> list[torch.Tensor]:
        zs = []
        for weight, bias in self.layer_params:
            z = linear(x, weight, bias)
            zs.append(z)
            x = self.act(z)
        return zs
