"""A few episodes of a fixed policy (zero action, uniform random actions) on a freshly added env, so the user
sees what the task pays before training on it: standing still should score little, and an episode that never
ends by the health check says the body may not be able to fall."""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np


@dataclass(frozen=True)
class ProbeResult:
    policy: str  # "zero" or "random"
    returns: list[float]
    lengths: list[int]
    fell: list[bool]  # the episode ended by the health check (terminated), not by the time limit
    distances: list[float]  # forward distance travelled

    @property
    def mean_return(self) -> float:
        return float(np.mean(self.returns))

    @property
    def mean_length(self) -> float:
        return float(np.mean(self.lengths))


def probe(env: gym.Env, policy: str, episodes: int = 1, seed: int = 0) -> ProbeResult:
    """Run `episodes` episodes of the zero action or of actions drawn uniformly from the action box."""
    if policy not in ("zero", "random"):
        raise ValueError(f"unknown probe policy {policy!r}")
    space = env.action_space
    rng = np.random.default_rng(seed)
    returns, lengths, fell, distances = [], [], [], []
    for episode in range(episodes):
        env.reset(seed=seed + episode)
        start = env.unwrapped.forward_position()
        total, steps, terminated, truncated = 0.0, 0, False, False
        while not (terminated or truncated):
            action = (np.zeros(space.shape, dtype=space.dtype) if policy == "zero"
                      else rng.uniform(space.low, space.high).astype(space.dtype))
            _, reward, terminated, truncated, _ = env.step(action)
            total += float(reward)
            steps += 1
        returns.append(total)
        lengths.append(steps)
        fell.append(bool(terminated))
        distances.append(env.unwrapped.forward_position() - start)
    return ProbeResult(policy, returns, lengths, fell, distances)
