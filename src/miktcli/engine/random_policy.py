"""The random policy's return on a target: the zero of the normalised scores (studies.aggregates).

The random policy draws every action uniformly from the environment's action box (the Atari convention the
normalisation comes from), one seeded stream per target; its return is the mean over whole episodes, each
ending by termination or the 1,000-step time limit, as in training. The committed protocol is 100 episodes
from seed 0 (the project's committed random-policy returns are measured that way).
"""

from __future__ import annotations

import numpy as np

from miktcli.envs.factory import make_env

POLICY = "uniform over the action box"
EPISODES = 100  # the committed protocol
SEED = 0


def random_returns(target: str, episodes: int = EPISODES, seed: int = SEED) -> dict:
    """One target's random-policy returns: their mean and sample std, the mean episode length, and each return."""
    env = make_env(target)
    env.action_space.seed(seed)
    returns, lengths = [], []
    try:
        for episode in range(episodes):
            env.reset(seed=seed + episode)
            total, steps, done = 0.0, 0, False
            while not done:
                _, reward, terminated, truncated, _ = env.step(env.action_space.sample())
                total, steps, done = total + float(reward), steps + 1, terminated or truncated
            returns.append(total)
            lengths.append(steps)
    finally:
        env.close()
    return {"episodes": episodes, "seed": seed, "return_mean": float(np.mean(returns)),
            "return_std": float(np.std(returns, ddof=1)) if episodes > 1 else 0.0,
            "length_mean": float(np.mean(lengths)), "returns": returns}
