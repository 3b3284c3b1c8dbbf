"""The policy/value modules the PPO engine trains, and the interface every one of them follows."""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import nn

from miktcli.engine.nets import MLP, ObsNormalizer

LOG_2PI = math.log(2.0 * math.pi)
TEACHER_FREE = "teacher-free"  # the phase in which a transfer method's student runs without its teachers


def over_rows(param: torch.Tensor) -> torch.Tensor:
    """A state-independent parameter (D,) as it is; stacked over seeds (S, D), as (S, 1, D), so that it meets
    each seed's own rows (S, B, D) in the seeds-together update (miktcli.engine.together)."""
    return param if param.dim() == 1 else param.unsqueeze(-2)


def gaussian_log_prob(actions: torch.Tensor, mean: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """Log-density of a diagonal Gaussian, written out: cheaper than torch.distributions on tiny batches."""
    log_std = over_rows(log_std)
    z = (actions - mean) * torch.exp(-log_std)
    return -(0.5 * z.square() + log_std + 0.5 * LOG_2PI).sum(-1)


def gaussian_kl(mean: torch.Tensor, log_std: torch.Tensor, old_mean: torch.Tensor, old_log_std: torch.Tensor):
    """KL(new || old) between diagonal Gaussians, per sample."""
    log_std, old_log_std = over_rows(log_std), over_rows(old_log_std)
    var_ratio = torch.exp(2.0 * (log_std - old_log_std))
    return (0.5 * (var_ratio + (mean - old_mean).square() * torch.exp(-2.0 * old_log_std) - 1.0)
            - (log_std - old_log_std)).sum(-1)


class ActorCritic(nn.Module):
    """Interface: what the PPO engine needs from a policy/value module.

    Observations reaching `action_mean`, `value` and `evaluate_actions` are already normalised by
    `obs_normalizer`. `evaluate_actions` also returns the module's own extra loss terms, already weighted;
    the engine adds them to the PPO loss and logs them.
    """

    obs_normalizer: ObsNormalizer
    log_std: nn.Parameter

    def action_mean(self, obs: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def value(self, obs: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def evaluate_actions(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, dict[str, torch.Tensor]]:
        return self.action_mean(obs), self.value(obs), {}

    def mean_and_value(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """`evaluate_actions(obs)`'s mean and value without its extra loss terms (the pass over the whole
        rollout after it, which needs no losses); the same numbers."""
        mean, value, _ = self.evaluate_actions(obs)
        return mean, value

    def rollout_actor(self, obs: torch.Tensor) -> Callable[[], torch.Tensor]:
        """A function computing `action_mean(obs)` for the rollout's fixed input tensor `obs` (refilled in
        place each step), called under torch.inference_mode. A module may return one that reuses buffers; it
        must give the same bits as `action_mean`."""
        return lambda: self.action_mean(obs)

    def set_progress(self, fraction: float) -> None:
        """Called before each iteration with the fraction of training done (for schedules)."""

    def restore_progress(self, fraction: float) -> None:
        """Called on resume with the fraction of the checkpoint's last iteration: put the schedule there
        without acting on the way (what it did then is in the checkpoint's weights)."""
        self.set_progress(fraction)

    def phase(self, fraction: float) -> str:
        """The schedule's phase at a fraction of training; a run keeps a checkpoint at every change."""
        return "train"

    def optional_state(self) -> set[str]:
        """State keys a checkpoint may lack (added to the module after older checkpoints were written); they
        load with the module's initial values."""
        return set()

    def ignores_state(self, key: str) -> bool:
        """Whether a checkpoint's tensor this module lacks may be left out on loading (e.g. data kept for
        an option the checkpoint's run had and this one has not: a branch that changes it)."""
        return False

    def handover_details(self) -> dict[str, float]:
        """What the module measured when it handed over at its schedule's drop (recorded in the card)."""
        return {}

    def observe_rollout(self, obs: torch.Tensor, next_fraction: float) -> None:
        """Called once per iteration, after the update and without gradients, with the rollout's normalised
        observations and the fraction of training the next iteration starts at: a module may keep running
        statistics of them (as buffers, so checkpoints hold them)."""

    def diagnostics(self) -> dict[str, float]:
        """Scalars worth logging every iteration (e.g. mixing weights)."""
        return {}

    def act(self, raw_obs: torch.Tensor, deterministic: bool = True) -> torch.Tensor:
        """Evaluation entry point: raw observations in, actions out."""
        mean = self.action_mean(self.obs_normalizer(raw_obs))
        if deterministic:
            return mean
        return mean + torch.exp(self.log_std) * torch.randn_like(mean)


class GaussianActorCritic(ActorCritic):
    """Separate MLPs for policy and value (tanh; an imported teacher may be relu), state-independent log-std
    initialised to 0."""

    def __init__(self, obs_dim: int, act_dim: int, pi_hidden=(64, 64), vf_hidden=(64, 64), activation: str = "tanh"):
        super().__init__()
        self.obs_normalizer = ObsNormalizer(obs_dim)
        self.pi = MLP(obs_dim, list(pi_hidden), act_dim, out_gain=0.01, activation=activation)
        self.vf = MLP(obs_dim, list(vf_hidden), 1, out_gain=1.0, activation=activation)
        self.log_std = nn.Parameter(torch.zeros(act_dim))

    def action_mean(self, obs: torch.Tensor) -> torch.Tensor:
        return self.pi(obs)

    def rollout_actor(self, obs: torch.Tensor) -> Callable[[], torch.Tensor]:
        return self.pi.rollout_forward(obs)

    def value(self, obs: torch.Tensor) -> torch.Tensor:
        return self.vf(obs).squeeze(-1)
