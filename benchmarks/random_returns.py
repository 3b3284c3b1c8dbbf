"""The random policy's return on each target: the zero of the normalised scores (benchmarks/aggregate_report.py).

The random policy draws every action uniformly from the environment's action box (the Atari convention the
normalisation comes from), one seeded stream per target; its return is the mean over whole episodes, each
ending by termination or the 1,000-step time limit, as in training. Measured once and committed:

    PYTHONPATH=src python benchmarks/random_returns.py --out benchmarks/results/random-policy.json
"""

from __future__ import annotations

import argparse
import json
import subprocess
from pathlib import Path

import numpy as np

from miktcli.envs.factory import make_env
from miktcli.registry.files import write_text_atomic

TARGETS = ["centipede-six", "centipede-eight", "cp-centipede-six", "cp-centipede-eight", "ant"]


def random_returns(target: str, episodes: int, seed: int) -> dict:
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--targets", nargs="+", default=TARGETS)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if args.episodes < 1:
        raise SystemExit("Error: --episodes must be at least 1")
    code = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    data = {"policy": "uniform over the action box", "code_version": code,
            "command": f"PYTHONPATH=src python benchmarks/random_returns.py --out {args.out} --episodes "
                       f"{args.episodes} --seed {args.seed}",
            "targets": {t: random_returns(t, args.episodes, args.seed) for t in args.targets}}
    write_text_atomic(args.out, json.dumps(data, indent=1) + "\n")


if __name__ == "__main__":
    main()
