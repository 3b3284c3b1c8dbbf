"""The random policies' returns on a target: the zero of the normalised scores (studies.aggregates), and the
policy PPO starts from, reported beside it.

The random policy draws every action uniformly from the environment's action box (the Atari convention the
normalisation comes from), one seeded stream per target. The initial policy draws N(0, 1) on every action
dimension and hands it to the environment unclipped: what an untrained Gaussian policy (mean ≈ 0, log-std 0)
does with the engine's raw actions, so it scores well below the uniform policy on the centipedes. Each return
is the mean over whole episodes, each ending by termination or the 1,000-step time limit, as in training. The
committed protocol is 100 episodes from seed 0 (the project's committed random-policy returns are measured
that way).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from miktcli.envs.factory import make_env

POLICY = "uniform over the action box"
INITIAL_POLICY = "N(0, 1) on every action dimension, unclipped (the policy PPO starts from)"
EPISODES = 100  # the committed protocol
SEED = 0


def random_returns(target: str, episodes: int = EPISODES, seed: int = SEED) -> dict:
    """One target's random-policy returns: their mean and sample std, the mean episode length, and each return."""
    def uniform(env, _rng: np.random.Generator) -> np.ndarray:
        return env.action_space.sample()

    return _returns(target, episodes, seed, uniform)


def initial_policy_returns(target: str, episodes: int = EPISODES, seed: int = SEED) -> dict:
    """The same for the initial policy, N(0, 1) per action dimension, unclipped."""
    def standard_normal(env, rng: np.random.Generator) -> np.ndarray:
        return rng.standard_normal(env.action_space.shape)

    return _returns(target, episodes, seed, standard_normal)


def _returns(target: str, episodes: int, seed: int, act: Callable[[object, np.random.Generator], np.ndarray]) -> dict:
    env = make_env(target)
    env.action_space.seed(seed)
    rng = np.random.default_rng(seed)
    returns, lengths = [], []
    try:
        for episode in range(episodes):
            env.reset(seed=seed + episode)
            total, steps, done = 0.0, 0, False
            while not done:
                _, reward, terminated, truncated, _ = env.step(act(env, rng))
                total, steps, done = total + float(reward), steps + 1, terminated or truncated
            returns.append(total)
            lengths.append(steps)
    finally:
        env.close()
    return {"episodes": episodes, "seed": seed, "return_mean": float(np.mean(returns)),
            "return_std": float(np.std(returns, ddof=1)) if episodes > 1 else 0.0,
            "length_mean": float(np.mean(lengths)), "returns": returns}
