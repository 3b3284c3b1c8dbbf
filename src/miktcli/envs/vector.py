"""A minimal synchronous vector of environments with same-step autoreset.

On the step where an episode ends, the env is reset at once: the returned observation is the new
episode's first one, and the last observation of the finished episode is handed back separately so a
truncated episode can be bootstrapped. No dummy transition ever reaches the rollout buffer.

Where every env has a lean stepper (envs/lean.py: this package's own families, gymnasium's Ant-v4 and
Hopper-v5) the steps go through it, bit-identical to `env.step`, and this class counts the time limit;
resets always go through the env itself.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from miktcli.envs.failures import env_failure
from miktcli.envs.lean import LeanStepper, lean_stepper
from miktcli.errors import MiktError

_INTEGRATION = mujoco.mjtState.mjSTATE_INTEGRATION
# Derived quantities that reward code reads *before* the next mj_step (Ant's and the centipede's "x before").
# After mj_step they describe the last sub-step's start, not the integrated state, so a resumed env gets the
# saved values back rather than fresh ones from mj_forward: that is what makes a resume bit-exact.
_NO_LIMIT = 2**62  # an env without a time limit never truncates
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
    """`lean=False` steps every env through gymnasium (the reference path; also taken wherever an env has
    no lean stepper). `self.lean` says which path runs."""

    def __init__(self, envs: list[gym.Env], seed: int, clip_actions: bool = False, lean: bool = True):
        self.envs = envs
        self.clip_actions = clip_actions
        self.num = len(envs)
        self.action_low = envs[0].action_space.low.astype(np.float32)
        self.action_high = envs[0].action_space.high.astype(np.float32)
        self._returns = np.zeros(self.num)
        self._lengths = np.zeros(self.num, dtype=np.int64)
        self._obs = np.stack([self._reset(env, seed=seed + i) for i, env in enumerate(envs)])
        found = [lean_stepper(env) for env in envs] if lean else []
        self.lean = bool(found) and all(f is not None for f in found)
        self._steppers: list[LeanStepper] = [f[0] for f in found] if self.lean else []  # type: ignore[index]
        self._limits = [_NO_LIMIT if f[1] is None else int(f[1]) for f in found] if self.lean else []  # type: ignore[index]

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
        if self.lean:
            return self._step_lean(actions)
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

    def _step_lean(self, actions: np.ndarray) -> StepResult:
        rewards = np.empty(self.num)
        terminated = np.zeros(self.num, dtype=bool)
        truncated = np.zeros(self.num, dtype=bool)
        next_obs = np.empty_like(self._obs)
        result = StepResult(next_obs, rewards, terminated, truncated)
        returns, lengths = self._returns, self._lengths
        i = 0
        try:  # one try around the loop (free until it raises); i names the env that failed
            for i, stepper in enumerate(self._steppers):
                reward, term = stepper.step(actions[i], next_obs[i])
                rewards[i] = reward
                returns[i] += reward
                lengths[i] += 1
                if term or lengths[i] >= self._limits[i]:
                    terminated[i], truncated[i] = term, not term
                    if not term:
                        result.final_obs[i] = next_obs[i].copy()
                    result.finished.append((float(returns[i]), int(lengths[i])))
                    returns[i], lengths[i] = 0.0, 0
                    next_obs[i] = self._reset(self.envs[i])
        except MiktError:
            raise
        except Exception as err:  # noqa: BLE001 - an env's own code: name its spec, not a mikt bug
            raise env_failure(self.envs[i], err, "step") from err
        self._obs = next_obs
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
            # On the lean path the env's own counter does not run; the episode length is the elapsed count.
            elapsed = self._lengths[i] if self.lean else getattr(counter, _elapsed_attr(counter)) or 0
            facts.append({"rng": u.np_random.bit_generator.state, "elapsed": int(elapsed)})
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
