"""Throughput, side by side in one process: this engine's PPO, Stable-Baselines3's PPO, MIKT, physics limit.

    python benchmarks/throughput.py [--steps 20480] [--env ant] [--json benchmarks/results/throughput.json]

Same env (Ant, the paper's 111-dim layout), same hyper-parameters (paper settings, 1 env, one thread).
Reports env-steps/s and their ratio, this engine's split into env / inference / update time, the
physics-only limit (mj_step x frame_skip), the MIKT update cost relative to a plain PPO update on the same
target, and peak resident memory. Needs `pip install -e .[bench]` for Stable-Baselines3.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import sys
import time
import warnings
from pathlib import Path

import mujoco
import torch

from miktcli.envs import load_spec, make_env
from miktcli.methods.mikt import MiktActorCritic, MiktConfig
from miktcli.policies import GaussianActorCritic
from miktcli.ppo import PPOConfig, PPOTrainer


def rss_mib() -> float:
    """Current resident set size (Linux), in MiB."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 2**20


def peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def physics_limit(env_name: str, steps: int = 5000) -> float:
    env = make_env(env_name)
    env.reset(seed=0)
    model, data = env.unwrapped.model, env.unwrapped.data
    frame_skip = getattr(env.unwrapped, "frame_skip", 5)
    data.ctrl[:] = 0.1
    t = time.perf_counter()
    for _ in range(steps):
        mujoco.mj_step(model, data, nstep=frame_skip)
    return steps / (time.perf_counter() - t)


def run_engine(env_name: str, agent, steps: int, seed: int, kl_coef: float = 0.0) -> dict:
    trainer = PPOTrainer(agent, lambda: make_env(env_name), PPOConfig(kl_coef=kl_coef), steps, seed)
    totals = {"time_env": 0.0, "time_inference": 0.0, "time_rollout": 0.0, "time_update": 0.0}
    rss = []
    t = time.perf_counter()
    for m in trainer.run():
        for k in totals:
            totals[k] += m[k]
        rss.append(rss_mib())
    wall = time.perf_counter() - t
    trainer.close()
    n = trainer.global_step
    return {
        "steps": n, "wall_s": wall, "steps_per_sec": n / wall,
        "rollout_steps_per_sec": n / totals["time_rollout"],
        "us_per_step": {k[5:]: 1e6 * v / n for k, v in totals.items()},
        "update_s_per_iteration": totals["time_update"] / trainer.iteration,
        "rss_first_iteration_mib": rss[0], "rss_last_iteration_mib": rss[-1],
    }


def run_sb3(env_name: str, steps: int, seed: int) -> dict:
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    venv = VecNormalize(DummyVecEnv([lambda: make_env(env_name)]), norm_obs=True, norm_reward=True,
                        clip_obs=10.0, clip_reward=10.0, gamma=0.99)
    model = PPO(
        "MlpPolicy", venv, n_steps=2048, batch_size=64, n_epochs=10, learning_rate=lambda f: 3e-4 * f,
        gamma=0.99, gae_lambda=0.95, clip_range=0.2, ent_coef=0.0, vf_coef=0.5, max_grad_norm=0.5,
        policy_kwargs={"net_arch": {"pi": [64, 64], "vf": [64, 64]}, "activation_fn": torch.nn.Tanh,
                       "log_std_init": 0.0, "ortho_init": True},
        seed=seed, device="cpu", verbose=0,
    )
    t = time.perf_counter()
    model.learn(total_timesteps=steps)
    wall = time.perf_counter() - t
    return {"steps": steps, "wall_s": wall, "steps_per_sec": steps / wall}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="ant")
    parser.add_argument("--steps", type=int, default=20480)
    parser.add_argument("--teacher-env", default="centipede-six", help="shape of the (untrained) MIKT teacher")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args()
    torch.set_num_threads(1)
    warnings.filterwarnings("ignore")
    spec = load_spec(args.env)

    out: dict = {"env": args.env, "steps": args.steps, "torch_threads": torch.get_num_threads(),
                 "machine": platform.machine(), "python": sys.version.split()[0], "torch": torch.__version__}
    out["physics_limit_steps_per_sec"] = physics_limit(args.env)
    torch.manual_seed(args.seed)
    out["mikt_engine_ppo"] = run_engine(args.env, GaussianActorCritic(spec.obs_dim, spec.act_dim), args.steps,
                                        args.seed)
    teacher_spec = load_spec(args.teacher_env)
    teacher = GaussianActorCritic(teacher_spec.obs_dim, teacher_spec.act_dim)
    teacher.requires_grad_(False)
    mikt_agent = MiktActorCritic(spec.obs_dim, spec.act_dim, [teacher], MiktConfig(coupling_schedule="constant"))
    out["mikt_engine_mikt"] = run_engine(args.env, mikt_agent, args.steps, args.seed, kl_coef=0.05)
    out["peak_rss_mib_before_sb3"] = peak_rss_mib()
    try:
        out["stable_baselines3_ppo"] = run_sb3(args.env, args.steps, args.seed)
    except ImportError:
        out["stable_baselines3_ppo"] = None
    ours = out["mikt_engine_ppo"]
    out["ratios"] = {
        "ppo_vs_sb3": (ours["steps_per_sec"] / out["stable_baselines3_ppo"]["steps_per_sec"]
                       if out["stable_baselines3_ppo"] else None),
        "rollout_vs_physics_limit": ours["rollout_steps_per_sec"] / out["physics_limit_steps_per_sec"],
        "mikt_update_vs_ppo_update": out["mikt_engine_mikt"]["update_s_per_iteration"]
        / ours["update_s_per_iteration"],
        "mikt_vs_ppo_end_to_end": out["mikt_engine_mikt"]["steps_per_sec"] / ours["steps_per_sec"],
    }
    out["peak_rss_mib"] = peak_rss_mib()

    sb3 = out["stable_baselines3_ppo"]
    split = ours["us_per_step"]
    print(f"env {args.env}, {args.steps} steps each, 1 env, 1 thread")
    print(f"physics-only limit (mj_step x frame_skip): {out['physics_limit_steps_per_sec']:8.0f} steps/s")
    print(f"this engine, PPO:                          {ours['steps_per_sec']:8.0f} steps/s "
          f"(rollout phase {ours['rollout_steps_per_sec']:.0f} steps/s)")
    print(f"  per env step: env {split['env']:.0f} us, inference {split['inference']:.0f} us, "
          f"update {split['update']:.0f} us")
    print(f"this engine, MIKT (1 teacher):             {out['mikt_engine_mikt']['steps_per_sec']:8.0f} steps/s")
    if sb3:
        print(f"Stable-Baselines3 PPO:                     {sb3['steps_per_sec']:8.0f} steps/s")
    r = out["ratios"]
    if r["ppo_vs_sb3"]:
        print(f"ratio PPO / SB3:                  {r['ppo_vs_sb3']:.2f}x")
    print(f"rollout / physics limit:          {100 * r['rollout_vs_physics_limit']:.0f} %")
    print(f"MIKT update / PPO update:         {r['mikt_update_vs_ppo_update']:.2f}x")
    print(f"RSS after first / last iteration: {ours['rss_first_iteration_mib']:.0f} / "
          f"{ours['rss_last_iteration_mib']:.0f} MiB; peak before SB3 {out['peak_rss_mib_before_sb3']:.0f} MiB, "
          f"overall {out['peak_rss_mib']:.0f} MiB")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
