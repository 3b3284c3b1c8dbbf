"""A minimal synchronous vector of environments with same-step autoreset.

On the step where an episode ends, the env is reset at once: the returned observation is the new
episode's first one, and the last observation of the finished episode is handed back separately so a
truncated episode can be bootstrapped. No dummy transition ever reaches the rollout buffer.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from miktcli.envs.failures import env_failure
from miktcli.errors import MiktError

_INTEGRATION = mujoco.mjtState.mjSTATE_INTEGRATION
# Derived quantities that reward code reads *before* the next mj_step (Ant's and the centipede's "x before").
# After mj_step they describe the last sub-step's start, not the integrated state, so a resumed env gets the
# saved values back rather than fresh ones from mj_forward: that is what makes a resume bit-exact.
_STALE_DERIVED = ("xpos", "xquat", "xipos", "geom_xpos", "subtree_com")


def _time_limit(env: gym.Env) -> Any:
    """The object that counts the episode's steps: gymnasium's TimeLimit wrapper, or the env itself."""
    layer = env
    while isinstance(layer, gym.Wrapper):
        if isinstance(layer, gym.wrappers.TimeLimit):
            return layer
        layer = layer.env
    return layer


def _elapsed_attr(counter: Any) -> str:
    return "_elapsed_steps" if isinstance(counter, gym.wrappers.TimeLimit) else "_elapsed"


@dataclass
class StepResult:
    obs: np.ndarray  # (n, obs_dim) next observations (first obs of a new episode where one ended)
    rewards: np.ndarray  # (n,)
    terminated: np.ndarray  # (n,) bool
    truncated: np.ndarray  # (n,) bool
    final_obs: dict[int, np.ndarray] = field(default_factory=dict)  # env index -> last obs, truncated only
    finished: list[tuple[float, int]] = field(default_factory=list)  # (return, length) of ended episodes


class SyncEnvs:
    def __init__(self, envs: list[gym.Env], seed: int, clip_actions: bool = False):
        self.envs = envs
        self.clip_actions = clip_actions
        self.num = len(envs)
        self.action_low = envs[0].action_space.low.astype(np.float32)
        self.action_high = envs[0].action_space.high.astype(np.float32)
        self._returns = np.zeros(self.num)
        self._lengths = np.zeros(self.num, dtype=np.int64)
        self._obs = np.stack([self._reset(env, seed=seed + i) for i, env in enumerate(envs)])

    @staticmethod
    def _reset(env: gym.Env, **kwargs: Any) -> np.ndarray:
        try:
            return env.reset(**kwargs)[0]
        except MiktError:
            raise
        except Exception as err:  # noqa: BLE001 - an env's own code: name its spec, not a mikt bug
            raise env_failure(env, err, "reset") from err

    @property
    def obs(self) -> np.ndarray:
        return self._obs

    def step(self, actions: np.ndarray) -> StepResult:
        # The buffer always keeps the raw sample; the env gets it raw too unless asked (see PPOConfig).
        if self.clip_actions:
            actions = np.clip(actions, self.action_low, self.action_high)
        rewards = np.empty(self.num)
        terminated = np.zeros(self.num, dtype=bool)
        truncated = np.zeros(self.num, dtype=bool)
        result = StepResult(self._obs, rewards, terminated, truncated)
        next_obs = np.empty_like(self._obs)
        for i, env in enumerate(self.envs):
            try:
                obs, reward, term, trunc, _ = env.step(actions[i])
            except MiktError:
                raise
            except Exception as err:  # noqa: BLE001 - an env's own code: name its spec, not a mikt bug
                raise env_failure(env, err, "step") from err
            rewards[i] = reward
            self._returns[i] += reward
            self._lengths[i] += 1
            if term or trunc:
                terminated[i], truncated[i] = term, trunc and not term
                if truncated[i]:
                    result.final_obs[i] = obs
                result.finished.append((float(self._returns[i]), int(self._lengths[i])))
                self._returns[i], self._lengths[i] = 0.0, 0
                obs = self._reset(env)
            next_obs[i] = obs
        self._obs = next_obs
        result.obs = next_obs
        return result

    # --- state for an exact resume ---------------------------------------------------------------------
    def state(self) -> tuple[dict[str, np.ndarray], list[dict[str, Any]]]:
        """Everything the next step depends on: arrays (for safetensors) and small JSON facts."""
        arrays: dict[str, np.ndarray] = {"obs": self._obs.copy(), "returns": self._returns.copy(),
                                         "lengths": self._lengths.copy()}
        facts = []
        for i, env in enumerate(self.envs):
            u = env.unwrapped
            physics = np.empty(mujoco.mj_stateSize(u.model, _INTEGRATION))
            mujoco.mj_getState(u.model, u.data, physics, _INTEGRATION)
            arrays[f"physics.{i}"] = physics
            for name in _STALE_DERIVED:
                arrays[f"{name}.{i}"] = getattr(u.data, name).copy()
            counter = _time_limit(env)
            facts.append({"rng": u.np_random.bit_generator.state,
                          "elapsed": int(getattr(counter, _elapsed_attr(counter)) or 0)})
        return arrays, facts

    def load_state(self, arrays: dict[str, np.ndarray], facts: list[dict[str, Any]]) -> None:
        if len(facts) != self.num:
            raise ValueError(f"saved state is for {len(facts)} envs, this run has {self.num}")
        for i, (env, fact) in enumerate(zip(self.envs, facts, strict=True)):
            u = env.unwrapped
            mujoco.mj_setState(u.model, u.data, arrays[f"physics.{i}"], _INTEGRATION)
            mujoco.mj_forward(u.model, u.data)
            for name in _STALE_DERIVED:
                getattr(u.data, name)[...] = arrays[f"{name}.{i}"]
            u.np_random.bit_generator.state = fact["rng"]
            counter = _time_limit(env)
            setattr(counter, _elapsed_attr(counter), fact["elapsed"])
        self._obs = arrays["obs"].copy()
        self._returns = arrays["returns"].copy()
        self._lengths = arrays["lengths"].copy()

    def close(self) -> None:
        for env in self.envs:
            env.close()
