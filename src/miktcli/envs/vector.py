"""A minimal synchronous vector of environments with same-step autoreset.

On the step where an episode ends, the env is reset at once: the returned observation is the new
episode's first one, and the last observation of the finished episode is handed back separately so a
truncated episode can be bootstrapped. No dummy transition ever reaches the rollout buffer.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np


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
        self._obs = np.stack([env.reset(seed=seed + i)[0] for i, env in enumerate(envs)])

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
            obs, reward, term, trunc, _ = env.step(actions[i])
            rewards[i] = reward
            self._returns[i] += reward
            self._lengths[i] += 1
            if term or trunc:
                terminated[i], truncated[i] = term, trunc and not term
                if truncated[i]:
                    result.final_obs[i] = obs
                result.finished.append((float(self._returns[i]), int(self._lengths[i])))
                self._returns[i], self._lengths[i] = 0.0, 0
                obs, _ = env.reset()
            next_obs[i] = obs
        self._obs = next_obs
        result.obs = next_obs
        return result

    def close(self) -> None:
        for env in self.envs:
            env.close()
