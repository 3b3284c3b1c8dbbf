"""Stable-Baselines3's PPO on Ant as a user would write it: the paper's hyper-parameters, VecNormalize, 1 env.

    python benchmarks/sb3_ppo_script.py [--steps 30720] [--seed 0]

benchmarks/throughput.py times this script as a whole process against `mikt teacher train ant`, and uses
`make_model` in process. Ant-v4 with contact forces is the paper's 111-dim layout (as envspecs/ant.toml).
"""

from __future__ import annotations

import argparse
import warnings


def make_model(seed: int, make_env=None):
    import gymnasium as gym
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    def ant():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return gym.make("Ant-v4", use_contact_forces=True, max_episode_steps=1000, disable_env_checker=True)

    venv = VecNormalize(DummyVecEnv([make_env or ant]), norm_obs=True, norm_reward=True, clip_obs=10.0,
                        clip_reward=10.0, gamma=0.99)
    return PPO(
        "MlpPolicy", venv, n_steps=2048, batch_size=64, n_epochs=10, learning_rate=lambda f: 3e-4 * f,
        gamma=0.99, gae_lambda=0.95, clip_range=0.2, ent_coef=0.0, vf_coef=0.5, max_grad_norm=0.5,
        policy_kwargs={"net_arch": {"pi": [64, 64], "vf": [64, 64]}, "activation_fn": torch.nn.Tanh,
                       "log_std_init": 0.0, "ortho_init": True},
        seed=seed, device="cpu", verbose=0,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=30720)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    import torch

    torch.set_num_threads(1)  # as mikt does (one process, one thread is fastest here)
    make_model(args.seed).learn(total_timesteps=args.steps)


if __name__ == "__main__":
    main()
