"""The PPO minibatch loss of the plain Gaussian actor-critic and its gradient, written out by hand
(PPOConfig.gradients = "by-hand").

On networks this small the autograd update is bound by the cost per op, not by arithmetic: the loss records
~70 ops and autograd replays ~120 more backwards, each with its allocation and bookkeeping, for a 64-row
minibatch of two 64-64 MLPs. Here the same loss is computed without recording anything, and its gradient
is the chain rule written out: the loss head (clipped surrogate, value loss, entropy and KL terms) down to
the action mean, log-std and value, then each MLP's layers, every weight's and bias's gradient written
straight into its `.grad` (the views FlatParameters made into one buffer), so no gradient is accumulated
or copied. Every loss option of PPOConfig is covered, with autograd's own conventions where the maths has
a choice: `max` splits its gradient evenly on a tie, `clamp` passes it at its bounds.

The numbers are autograd's to float rounding, not bit for bit (a gradient is summed in another order), so
it is a recorded option: the card says which path ran, and benchmarks/paired_numerics.py compares how the
two learn over paired seeds. Other agents (MIKT's mixed network) keep autograd: `unsupported` says why.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch.nn import functional as F

from miktcli.engine.nets import MLP
from miktcli.engine.policies import LOG_2PI, GaussianActorCritic

if TYPE_CHECKING:
    from miktcli.engine.ppo import Minibatch, PPOConfig

# what autograd's backward of each activation reads: the layer's output
_ACTIVATION_BACKWARD = {
    "tanh": torch.ops.aten.tanh_backward,
    "relu": lambda grad, out: torch.ops.aten.threshold_backward(grad, out, 0),
}


def unsupported(agent: torch.nn.Module) -> str | None:
    """Why `agent`'s update cannot have its gradient by hand, or None when it can: only the plain Gaussian
    actor-critic (PPO, VPG, MLPP and teacher training), every parameter trained."""
    if type(agent) is not GaussianActorCritic:
        return f"{type(agent).__name__} is not the plain actor-critic (PPO, VPG, MLPP); its update needs autograd"
    for net in (agent.pi, agent.vf):
        if net.activation not in _ACTIVATION_BACKWARD:
            return f"no hand-written backward for the activation '{net.activation}'"
    if not all(p.requires_grad for p in agent.parameters()):
        return "the agent has frozen parameters; the hand-written gradient trains every one"
    return None


def ratio_logs(pg_loss: torch.Tensor, v_loss: torch.Tensor, ratio: torch.Tensor, logratio: torch.Tensor,
               clip_range: float) -> dict[str, torch.Tensor]:
    """The logs every minibatch loss returns first (PPOTrainer.loss too, so both paths log alike): the two
    losses, the approximate KL, the clipped fraction and the largest ratio deviation, per row of the last dim."""
    change = ratio - 1.0
    deviation = change.abs()
    return {"loss_policy": pg_loss, "loss_value": v_loss, "approx_kl": (change - logratio).mean(-1),
            "clipfrac": (deviation > clip_range).float().mean(-1), "ratio_dev": deviation.amax(-1)}


class _Layers:
    """One MLP's forward, keeping each layer's output, and its backward into the parameters' `.grad`."""

    def __init__(self, net: MLP):
        self.net = net
        self.act = net.act  # MLP.forward's own activation
        self.act_backward = _ACTIVATION_BACKWARD[net.activation]

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        outputs = [x]
        for weight, bias in self.net.layer_params:
            x = self.act(F.linear(x, weight, bias))  # MLP.forward's kernels, so its bits
            outputs.append(x)
        return F.linear(x, *self.net.head_params), outputs

    def backward(self, grad_out: torch.Tensor, outputs: list[torch.Tensor]) -> None:
        """Write d loss / d parameter into every parameter's `.grad`, given d loss / d output (rows, out)."""
        weight, bias = self.net.head_params
        torch.mm(grad_out.t(), outputs[-1], out=weight.grad)
        torch.sum(grad_out, 0, out=bias.grad)
        grad_x = torch.mm(grad_out, weight)
        layers = self.net.layer_params
        for j in range(len(layers) - 1, -1, -1):
            weight, bias = layers[j]
            grad_z = self.act_backward(grad_x, outputs[j + 1])
            torch.mm(grad_z.t(), outputs[j], out=weight.grad)
            torch.sum(grad_z, 0, out=bias.grad)
            if j:
                grad_x = torch.mm(grad_z, weight)


class HandGradients:
    """`PPOTrainer.loss` and its backward for a GaussianActorCritic, by hand. Call it with a minibatch: it
    writes every parameter's gradient (no zeroing needed) and returns the logs `PPOTrainer.loss` returns,
    with the same keys in the same order."""

    def __init__(self, agent: GaussianActorCritic, config: PPOConfig):
        why = unsupported(agent)
        if why is not None:
            raise ValueError(why)
        self.agent, self.config = agent, config
        self.pi, self.vf = _Layers(agent.pi), _Layers(agent.vf)

    @torch.no_grad()
    def __call__(self, mb: Minibatch, old_log_std: torch.Tensor) -> dict[str, torch.Tensor]:
        cfg, agent = self.config, self.agent
        rows = mb.obs.shape[0]
        mean, pi_out = self.pi.forward(mb.obs)
        value, vf_out = self.vf.forward(mb.obs)
        value = value.squeeze(-1)
        log_std = agent.log_std

        # the surrogate, as PPOTrainer.loss computes it (gaussian_log_prob written out, to keep z)
        inv_std = torch.exp(-log_std)
        z = (mb.actions - mean) * inv_std
        new_logprob = -(0.5 * z.square() + log_std + 0.5 * LOG_2PI).sum(-1)
        logratio = new_logprob - mb.log_probs
        ratio = logratio.exp()
        adv = mb.advantages
        if cfg.normalize_advantage and rows > 1:
            adv = (adv - adv.mean(-1, keepdim=True)) / (adv.std(-1, keepdim=True) + 1e-8)
        unclipped = -adv * ratio
        clipped = -adv * ratio.clamp(1 - cfg.clip_range, 1 + cfg.clip_range)
        pg_loss = torch.max(unclipped, clipped).mean(-1)
        # d pg / d ratio: the unclipped branch's wherever it is the max; inside the clip range both branches
        # are the same number (a tie, split evenly, and clamp passes its half), outside it the clipped one
        # carries no gradient
        grad_logprob = ((unclipped >= clipped) * (-adv / rows) * ratio)[:, None]
        # d new_logprob / d mean = z / std; d / d log_std = z² − 1 (summed over rows)
        grad_rows = grad_logprob * z
        grad_mean = grad_rows * inv_std
        grad_log_std = (grad_rows * z - grad_logprob).sum(0)

        v_loss, grad_value = self._value_loss(value, mb)
        terms_logs: dict[str, torch.Tensor] = {}
        if cfg.ent_coef:
            entropy = (log_std + 0.5 * (1.0 + LOG_2PI)).sum(-1)
            terms_logs["loss_entropy"] = -cfg.ent_coef * entropy
            grad_log_std = grad_log_std - cfg.ent_coef
        if cfg.kl_coef:
            delta = log_std - old_log_std
            var_ratio = torch.exp(2.0 * delta)
            inv_old_var = torch.exp(-2.0 * old_log_std)
            diff = mean - mb.means
            kl = (0.5 * (var_ratio + diff.square() * inv_old_var - 1.0) - delta).sum(-1)
            terms_logs["loss_kl"] = cfg.kl_coef * kl.mean(-1)
            grad_mean = grad_mean + (cfg.kl_coef / rows) * diff * inv_old_var
            grad_log_std = grad_log_std + cfg.kl_coef * (var_ratio - 1.0)

        self.pi.backward(grad_mean, pi_out)
        self.vf.backward(grad_value[:, None], vf_out)
        log_std.grad.copy_(grad_log_std)
        return {**ratio_logs(pg_loss, v_loss, ratio, logratio, cfg.clip_range), **terms_logs}

    def _value_loss(self, value: torch.Tensor, mb: Minibatch) -> tuple[torch.Tensor, torch.Tensor]:
        """The value loss as PPOTrainer.loss defines it (unweighted, for the logs) and d (vf_coef · it) /
        d value."""
        cfg = self.config
        rows = value.shape[0]
        # CAT's unclipped term has no target (see PPOConfig.value_loss)
        error = value if cfg.value_loss == "cat-zero-target" else value - mb.returns
        v_error = error.square()
        if not cfg.clip_value_loss:
            scale = 1.0 if cfg.value_loss == "sb3" else 0.5
            return scale * v_error.mean(-1), (cfg.vf_coef * scale * 2.0 / rows) * error
        change = value - mb.values
        clipped_error = mb.values + change.clamp(-cfg.clip_range, cfg.clip_range) - mb.returns
        v_clipped_error = clipped_error.square()
        passes = (change.abs() <= cfg.clip_range)  # clamp's gradient, its bounds included
        if cfg.value_loss == "sb3":
            return v_clipped_error.mean(-1), (cfg.vf_coef * 2.0 / rows) * passes * clipped_error
        # 0.5 · max(unclipped², clipped²): the larger term's gradient, half each on a tie
        share = (v_error > v_clipped_error) + 0.5 * (v_error == v_clipped_error)
        grad = (cfg.vf_coef / rows) * (share * error + (1.0 - share) * passes * clipped_error)
        return 0.5 * torch.max(v_error, v_clipped_error).mean(-1), grad
