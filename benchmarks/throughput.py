"""Throughput, side by side in one process: this engine's PPO, Stable-Baselines3's PPO, MIKT, physics limit.

    python benchmarks/throughput.py [--steps 20480] [--env ant] [--json benchmarks/results/throughput.json]

Same env (Ant, the paper's 111-dim layout), same hyper-parameters (paper settings, 1 env, one thread).
Reports env-steps/s and their ratio, this engine's split into env / inference / update time, the
physics-only limit (mj_step x frame_skip), the MIKT update cost relative to a plain PPO update on the same
target (1, 2 and 3 teachers), eager and with `--compile` (PPOConfig.compile_loss; the compile's own time is
left out of the rates), the arithmetic of one minibatch update (FLOPs, forward + backward) for each, and peak
resident memory. Needs `pip install -e .[bench]` for Stable-Baselines3.
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
from miktcli.ppo import Minibatch, PPOConfig, PPOTrainer


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


def update_flops(trainer: PPOTrainer) -> int:
    """FLOPs of one minibatch's loss, forward and backward (torch's own counter)."""
    from torch.utils.flop_counter import FlopCounterMode

    cfg = trainer.config
    n, obs_dim, act_dim = cfg.minibatch_size, trainer.envs.obs.shape[1], trainer.agent.log_std.shape[0]
    mb = Minibatch(obs=torch.randn(n, obs_dim), actions=torch.randn(n, act_dim), log_probs=torch.randn(n),
                   means=torch.randn(n, act_dim), advantages=torch.randn(n), returns=torch.randn(n),
                   values=torch.randn(n))
    with FlopCounterMode(display=False) as counter:
        loss, _ = trainer.loss(mb, trainer.agent.log_std.detach().clone())
        loss.backward()
    trainer.flat.zero_grad()
    return counter.get_total_flops()


def run_engine(env_name: str, agent, steps: int, seed: int, kl_coef: float = 0.0,
               compile_loss: bool = False) -> dict:
    config = PPOConfig(kl_coef=kl_coef, compile_loss=compile_loss)
    trainer = PPOTrainer(agent, lambda: make_env(env_name), config, steps + config.batch_size, seed)
    flops = update_flops(trainer)
    totals = {"time_env": 0.0, "time_inference": 0.0, "time_rollout": 0.0, "time_update": 0.0}
    rss = []
    iterations = trainer.run()
    next(iterations)  # not timed: the first iteration compiles the loss (with --compile) and warms up
    t = time.perf_counter()
    for m in iterations:
        for k in totals:
            totals[k] += m[k]
        rss.append(rss_mib())
    wall = time.perf_counter() - t
    trainer.close()
    n = trainer.global_step - config.batch_size
    return {
        "steps": n, "wall_s": wall, "steps_per_sec": n / wall, "update_flops": flops,
        "rollout_steps_per_sec": n / totals["time_rollout"],
        "us_per_step": {k[5:]: 1e6 * v / n for k, v in totals.items()},
        "update_s_per_iteration": totals["time_update"] / (trainer.iteration - 1),
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
    teacher_spec = load_spec(args.teacher_env)

    def ppo_agent():
        torch.manual_seed(args.seed)
        return GaussianActorCritic(spec.obs_dim, spec.act_dim)

    def mikt_agent(num_teachers: int):
        torch.manual_seed(args.seed)
        teachers = [GaussianActorCritic(teacher_spec.obs_dim, teacher_spec.act_dim).requires_grad_(False)
                    for _ in range(num_teachers)]
        return MiktActorCritic(spec.obs_dim, spec.act_dim, teachers, MiktConfig(coupling_schedule="constant"))

    for compiled in (False, True):
        suffix = "_compiled" if compiled else ""
        out["mikt_engine_ppo" + suffix] = run_engine(args.env, ppo_agent(), args.steps, args.seed,
                                                     compile_loss=compiled)
        for k in (1, 2, 3) if not compiled else (1,):
            name = "mikt_engine_mikt" + ("" if k == 1 else f"_{k}_teachers") + suffix
            out[name] = run_engine(args.env, mikt_agent(k), args.steps, args.seed, kl_coef=0.05,
                                   compile_loss=compiled)
    out["peak_rss_mib_before_sb3"] = peak_rss_mib()
    try:
        out["stable_baselines3_ppo"] = run_sb3(args.env, args.steps, args.seed)
    except ImportError:
        out["stable_baselines3_ppo"] = None
    ours, ours_c = out["mikt_engine_ppo"], out["mikt_engine_ppo_compiled"]
    sb3_rate = out["stable_baselines3_ppo"]["steps_per_sec"] if out["stable_baselines3_ppo"] else None

    def update_ratio(mikt: str, ppo: str) -> float:
        return out[mikt]["update_s_per_iteration"] / out[ppo]["update_s_per_iteration"]

    out["ratios"] = {
        "ppo_vs_sb3": ours["steps_per_sec"] / sb3_rate if sb3_rate else None,
        "ppo_compiled_vs_sb3": ours_c["steps_per_sec"] / sb3_rate if sb3_rate else None,
        "rollout_vs_physics_limit": ours["rollout_steps_per_sec"] / out["physics_limit_steps_per_sec"],
        "mikt_update_vs_ppo_update": update_ratio("mikt_engine_mikt", "mikt_engine_ppo"),
        "mikt_2_teachers_update_vs_ppo_update": update_ratio("mikt_engine_mikt_2_teachers", "mikt_engine_ppo"),
        "mikt_3_teachers_update_vs_ppo_update": update_ratio("mikt_engine_mikt_3_teachers", "mikt_engine_ppo"),
        "mikt_update_vs_ppo_update_compiled": update_ratio("mikt_engine_mikt_compiled", "mikt_engine_ppo_compiled"),
        "mikt_update_flops_vs_ppo": out["mikt_engine_mikt"]["update_flops"] / ours["update_flops"],
        "compiled_vs_eager_ppo_update": update_ratio("mikt_engine_ppo_compiled", "mikt_engine_ppo"),
        "compiled_vs_eager_mikt_update": update_ratio("mikt_engine_mikt_compiled", "mikt_engine_mikt"),
        "mikt_vs_ppo_end_to_end": out["mikt_engine_mikt"]["steps_per_sec"] / ours["steps_per_sec"],
        "mikt_vs_ppo_end_to_end_compiled": out["mikt_engine_mikt_compiled"]["steps_per_sec"]
        / ours_c["steps_per_sec"],
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
    rows = {"MIKT (1 teacher)": "mikt_engine_mikt", "MIKT (2 teachers)": "mikt_engine_mikt_2_teachers",
            "MIKT (3 teachers)": "mikt_engine_mikt_3_teachers", "PPO, --compile": "mikt_engine_ppo_compiled",
            "MIKT (1 teacher), --compile": "mikt_engine_mikt_compiled"}
    for label, name in rows.items():
        print(f"this engine, {label + ':':30s} {out[name]['steps_per_sec']:8.0f} steps/s")
    if sb3:
        print(f"Stable-Baselines3 PPO:                     {sb3['steps_per_sec']:8.0f} steps/s")
    for key, value in out["ratios"].items():
        if value is not None:
            print(f"{key:40s} {value:.2f}")
    print(f"RSS after first / last iteration: {ours['rss_first_iteration_mib']:.0f} / "
          f"{ours['rss_last_iteration_mib']:.0f} MiB; peak before SB3 {out['peak_rss_mib_before_sb3']:.0f} MiB, "
          f"overall {out['peak_rss_mib']:.0f} MiB")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
