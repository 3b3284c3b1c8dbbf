"""One rollout of a trainer's envs, a step at a time.

`RolloutCollector` holds what one rollout writes (the Rollout's buffers, the sampling noise, the normaliser's
per-step views, the finished episodes) and splits a step in two around the policy's forward: `observe()` puts
the normalised observation where the actor reads it, `act(mean, ...)` samples, steps the envs and records.
A run alone (PPOTrainer.collect) calls them around its own actor; seeds trained together
(miktcli.engine.together) call every seed's `observe()`, run one batched forward for all of them, then every
seed's `act`. Either way each seed's numbers come from its own generator, normaliser and reward scaler.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from miktcli.engine.policies import ActorCritic
from miktcli.envs.mujoco_warnings import mujoco_warning_count
from miktcli.envs.vector import SyncEnvs


@dataclass
class Rollout:
    obs: np.ndarray  # (T, N, obs_dim) normalised, float32
    actions: np.ndarray  # (T, N, act_dim) unclipped samples
    rewards: np.ndarray  # (T, N) scaled
    terminated: np.ndarray
    dones: np.ndarray
    final_obs: dict[tuple[int, int], np.ndarray] = field(default_factory=dict)  # (t, i) -> normalised obs
    last_obs: np.ndarray | None = None  # normalised obs after the last step


class RolloutCollector:
    """One rollout of `n_steps` on `envs` with `agent`'s noise scale, its samples drawn from `rng`, its rewards
    scaled by `reward_scaler` (None: raw). `obs_in` is the (num_envs, obs_dim) float32 buffer the actor reads
    (a seed's row of a stacked buffer when seeds train together); one is made when none is given. The
    episodes that ended are in `finished` (return, length) for the trainer to keep."""

    def __init__(self, agent: ActorCritic, envs: SyncEnvs, n_steps: int, rng: np.random.Generator,
                 reward_scaler: Any | None, obs_in: np.ndarray | None = None):
        T, N = n_steps, envs.num
        obs_dim = envs.obs.shape[1]
        act_dim = agent.log_std.shape[0]
        self.envs, self.steps = envs, T
        self.ro = Rollout(
            obs=np.empty((T, N, obs_dim), np.float32), actions=np.empty((T, N, act_dim), np.float32),
            rewards=np.empty((T, N)), terminated=np.zeros((T, N)), dones=np.zeros((T, N)),
        )
        std = np.exp(agent.log_std.detach().numpy())
        self.noise = rng.standard_normal((T, N, act_dim)).astype(np.float32) * std
        self.normalizer = agent.obs_normalizer
        # The per-step pieces over buffers made once per rollout (the same bits as the module's own paths).
        self.fast_norm = self.normalizer.rollout(N)
        self.obs_in = np.empty((N, obs_dim), np.float32) if obs_in is None else obs_in
        self.reward_scaler = reward_scaler
        self.scale_one = self.reward_scaler.scale_one if self.reward_scaler is not None and N == 1 else None
        self.t = 0
        self.t_env = self.t_inf = 0.0
        self.finished: list[tuple[float, int]] = []
        self.obs_raw = envs.obs
        self.warnings_before = mujoco_warning_count()

    def observe(self) -> None:
        """This step's observation into the normaliser's statistics, and normalised into `obs_in`."""
        self.fast_norm.update(self.obs_raw)
        self.fast_norm.normalize_into(self.obs_raw, self.obs_in)

    def act(self, mean: np.ndarray, inference_s: float) -> None:
        """Sample around the policy's `mean` for `obs_in`, step the envs and record the step; `inference_s` is
        the time this step's normalising and forward took (for the metrics' time_inference)."""
        t, ro, clock = self.t, self.ro, time.perf_counter
        t0 = clock()
        actions = np.add(mean, self.noise[t], out=ro.actions[t])
        ro.obs[t] = self.obs_in
        t1 = clock()
        step = self.envs.step(actions)
        self.t_env += clock() - t1
        self.t_inf += inference_s + (t1 - t0)
        if step.finished:
            dones = step.terminated | step.truncated
            ro.terminated[t], ro.dones[t] = step.terminated, dones
            for i, final in step.final_obs.items():
                ro.final_obs[(t, i)] = self.normalizer.normalize_np(final[None])[0]
            self.finished += step.finished
        else:
            dones = step.terminated  # all False: nothing ended (the rows are zeros already)
        if self.scale_one is not None:
            ro.rewards[t, 0] = self.scale_one(float(step.rewards[0]), bool(dones[0]))
        else:
            ro.rewards[t] = (step.rewards if self.reward_scaler is None
                          else self.reward_scaler(step.rewards, dones))
        self.obs_raw = step.obs
        self.t = t + 1

    def finish(self) -> tuple[Rollout, dict[str, Any]]:
        """The rollout, with the last observation for bootstrapping, and its stats."""
        ro = self.ro
        ro.last_obs = self.normalizer.normalize_np(self.obs_raw)
        stats = {
            "time_env": self.t_env, "time_inference": self.t_inf,
            "episodes_finished": len(self.finished),
            # A diverging simulation (MuJoCo's "unstable" warnings): counted here instead of a log file.
            "sim_warnings": mujoco_warning_count() - self.warnings_before,
            "episode_return_iter": float(np.mean([r for r, _ in self.finished])) if self.finished else float("nan"),
        }
        return ro, stats
