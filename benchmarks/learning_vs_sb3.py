"""Learning speed, side by side: this engine's PPO against Stable-Baselines3's PPO on the same env and budget.

    python benchmarks/learning_vs_sb3.py run --impl sb3 --seeds 0 1 2 3 4
    python benchmarks/learning_vs_sb3.py run --impl mikt --seeds 0 1 2 3 4 [--variant NAME --set FIELD=VALUE ...]
    python benchmarks/learning_vs_sb3.py report        # table of every (implementation, variant) recorded

Paper settings on both sides: 2048-step rollouts, 10 epochs of 64, lr 3e-4 decaying linearly to 0, γ 0.99,
λ 0.95, clip 0.2, value clip 0.2, grad-norm clip 0.5, obs + reward normalisation, separate 64-64 tanh actor and
critic, log-std 0, Adam eps 1e-5, one env, one torch thread. Each (implementation, variant, seed) is one line of
the results file (JSON lines), written when the run ends, so the script resumes by skipping recorded runs.
Recorded per run: the training curve (mean return of the last 100 training episodes after every rollout) and a
deterministic evaluation of the final policy (normaliser frozen) on fresh seeds. `--set` overrides PPOConfig
fields of this engine (e.g. `--set value_loss=sb3`) so every ablation of the investigation is one variant.
Needs `pip install -e .[bench]` for Stable-Baselines3.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from miktcli.engine.episodes import run_episodes
from miktcli.engine.policies import GaussianActorCritic
from miktcli.engine.ppo import PPOConfig, PPOTrainer
from miktcli.envs import make_env

RESULTS = Path(__file__).resolve().parent / "results" / "learning-vs-sb3.jsonl"
# Curve points: steps, training return, then (recorded since the investigation began) these per-update values.
DIAGNOSTICS = ("explained_variance", "value_loss", "approx_kl", "clipfrac", "log_std_mean", "reward_scale")
EVAL_SEED = 10_000  # evaluation episodes never reuse training seeds


def parse_overrides(pairs: list[str]) -> dict:
    out = {}
    for pair in pairs:
        key, _, value = pair.partition("=")
        try:
            out[key] = json.loads(value)  # numbers, true/false
        except json.JSONDecodeError:
            out[key] = value  # a bare word, e.g. value_loss=sb3
    return out


def train_mikt(env_name: str, steps: int, seed: int, overrides: dict, episodes: int) -> dict:
    torch.manual_seed(seed)
    spec_env = make_env(env_name)
    obs_dim, act_dim = spec_env.observation_space.shape[0], spec_env.action_space.shape[0]
    agent = GaussianActorCritic(obs_dim, act_dim)
    trainer = PPOTrainer(agent, lambda: make_env(env_name), PPOConfig(**overrides), steps, seed)
    curve = []
    for m in trainer.run():
        # (steps, return, then diagnostics to set beside SB3's; see DIAGNOSTICS)
        curve.append((m["steps"], m["return_mean"], m["explained_variance"], m["loss_value"], m["approx_kl"],
                      m["clipfrac"], m["log_std_mean"], float(np.sqrt(trainer.reward_scaler.var[0]))))
    trainer.close()
    agent.obs_normalizer.frozen = True
    with torch.no_grad():
        res = run_episodes(lambda o: agent.act(o, True), spec_env, episodes, EVAL_SEED + seed,
                       clip_actions=overrides.get("clip_actions_for_env", False))
    spec_env.close()
    return {"curve": curve, "eval": res.summary()}


def train_sb3(env_name: str, steps: int, seed: int, episodes: int) -> dict:
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    venv = VecNormalize(DummyVecEnv([lambda: Monitor(make_env(env_name))]), gamma=0.99)
    model = PPO(
        "MlpPolicy", venv, n_steps=2048, batch_size=64, n_epochs=10, learning_rate=lambda f: 3e-4 * f,
        gamma=0.99, gae_lambda=0.95, clip_range=0.2, clip_range_vf=0.2, ent_coef=0.0, vf_coef=0.5,
        max_grad_norm=0.5, seed=seed, device="cpu", verbose=0,
        policy_kwargs={"net_arch": {"pi": [64, 64], "vf": [64, 64]}, "activation_fn": torch.nn.Tanh,
                       "log_std_init": 0.0, "ortho_init": True},
    )

    class Curve(BaseCallback):
        def __init__(self):
            super().__init__()
            self.curve = []

        def _on_step(self) -> bool:
            return True

        def _on_rollout_end(self) -> None:
            eps = self.model.ep_info_buffer
            ret = float(np.mean([e["r"] for e in eps])) if eps else float("nan")
            self.curve.append([self.num_timesteps, ret])

        def on_train_end_of_iteration(self) -> None:
            # The logger holds the last update's values; attach them to that iteration's point. SB3's value
            # loss is its own form (the clipped prediction's squared error, no 0.5): compare trends, not levels.
            logged = self.model.logger.name_to_value
            values = [logged.get(f"train/{k}") for k in ("explained_variance", "value_loss", "approx_kl",
                                                          "clip_fraction")]
            log_std = self.model.policy.log_std.detach().mean()
            self.curve[-1] += [None if v is None else float(v) for v in values]
            self.curve[-1] += [float(log_std), float(np.sqrt(venv.ret_rms.var))]

    cb = Curve()
    original_train = model.train

    def train_and_record() -> None:
        original_train()
        cb.on_train_end_of_iteration()

    model.train = train_and_record
    model.learn(total_timesteps=steps, callback=cb)
    # SB3 records the rollout's stats on the next rollout start; the last point is read after learn().
    venv.training, venv.norm_reward = False, False
    env = make_env(env_name)
    obs_rms = venv.obs_rms

    def act(obs: torch.Tensor) -> torch.Tensor:
        norm = np.clip((obs.numpy() - obs_rms.mean) / np.sqrt(obs_rms.var + venv.epsilon), -10, 10)
        action, _ = model.predict(norm.astype(np.float32), deterministic=True)
        return torch.as_tensor(action)

    res = run_episodes(act, env, episodes, EVAL_SEED + seed, clip_actions=True)  # SB3 clips for the env
    env.close()
    return {"curve": cb.curve, "eval": res.summary()}


def done_runs(path: Path) -> set[tuple[str, str, str, int, int]]:
    if not path.exists():
        return set()
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return {(r["impl"], r["variant"], r["env"], r["steps"], r["seed"]) for r in rows}


def cmd_run(args) -> None:
    torch.set_num_threads(1)
    warnings.filterwarnings("ignore")
    overrides = parse_overrides(args.set)
    variant = args.variant or ("default" if not overrides else ",".join(args.set))
    done = done_runs(args.out)
    for seed in args.seeds:
        key = (args.impl, variant, args.env, args.steps, seed)
        if key in done:
            print(f"skip {key}: recorded", flush=True)
            continue
        t = time.perf_counter()
        if args.impl == "sb3":
            result = train_sb3(args.env, args.steps, seed, args.eval_episodes)
        else:
            result = train_mikt(args.env, args.steps, seed, overrides, args.eval_episodes)
        row = {"impl": args.impl, "variant": variant, "overrides": overrides, "env": args.env, "steps": args.steps,
               "seed": seed, "seconds": time.perf_counter() - t, "machine": platform.node(), **result}
        args.out.parent.mkdir(parents=True, exist_ok=True)
        with args.out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(f"{args.impl}/{variant} seed {seed}: eval {result['eval']['return_mean']:.0f}, "
              f"train {result['curve'][-1][1]:.0f}, {row['seconds']:.0f} s", flush=True)


def value_at(curve: list, mark: int) -> float:
    points = [ret for steps, ret, *_ in curve if steps <= mark]
    return points[-1] if points else float("nan")


def cmd_report(args) -> None:
    rows = [json.loads(line) for line in args.out.read_text().splitlines() if line.strip()]
    groups: dict[tuple, list] = {}
    for r in rows:
        if r["env"] == args.env and r["steps"] == args.steps:
            groups.setdefault((r["impl"], r["variant"]), []).append(r)
    marks = [m for m in args.marks if m <= args.steps]
    sb3 = [r["eval"]["return_mean"] for r in groups.get(("sb3", "default"), [])]
    header = ["impl", "variant", "n", *[f"train @{m // 1000}k" for m in marks], "final eval", "eval / SB3"]
    print(f"{args.env}, {args.steps:,} steps; mean ± sample std (ddof 1) over seeds\n")
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for (impl, variant), rs in sorted(groups.items()):
        cells = []
        for m in marks:
            v = np.array([value_at(r["curve"], m) for r in rs])
            cells.append(f"{np.nanmean(v):.0f} ± {np.nanstd(v, ddof=1) if len(v) > 1 else 0:.0f}")
        ev = np.array([r["eval"]["return_mean"] for r in rs])
        ratio = f"{ev.mean() / np.mean(sb3):.2f}×" if sb3 else "—"
        sd = ev.std(ddof=1) if len(ev) > 1 else 0.0
        print(f"| {impl} | {variant} | {len(rs)} | " + " | ".join(cells) + f" | {ev.mean():.0f} ± {sd:.0f} | {ratio} |")


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    for name in ("run", "report"):
        p = sub.add_parser(name)
        p.add_argument("--env", default="hopper")
        p.add_argument("--steps", type=int, default=122_880)
        p.add_argument("--out", type=Path, default=RESULTS)
        if name == "run":
            p.add_argument("--impl", choices=["mikt", "sb3"], required=True)
            p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
            p.add_argument("--variant", default=None)
            p.add_argument("--set", action="append", default=[], help="PPOConfig FIELD=VALUE for --impl mikt")
            p.add_argument("--eval-episodes", type=int, default=10)
        else:
            p.add_argument("--marks", type=int, nargs="+", default=[20_480, 40_960, 61_440, 81_920, 102_400, 122_880])
    args = parser.parse_args(argv)
    cmd_run(args) if args.cmd == "run" else cmd_report(args)


if __name__ == "__main__":
    main(sys.argv[1:])
