"""The random policy's return on each target: the zero of the normalised scores (studies.aggregates).

The measurement is the library's (miktcli.engine.random_policy: uniform over the action box, one seeded stream per
target, whole episodes); a study measures the targets it lacks itself, into its folder's random-returns.json.
Measured once for the five targets and committed:

    PYTHONPATH=src python benchmarks/random_returns.py --out benchmarks/results/random-policy.json --episodes 100
"""

from __future__ import annotations

import argparse
import json
import subprocess
from pathlib import Path

from miktcli.engine.random_policy import EPISODES, POLICY, SEED, random_returns
from miktcli.registry.files import write_text_atomic

TARGETS = ["centipede-six", "centipede-eight", "cp-centipede-six", "cp-centipede-eight", "ant"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--targets", nargs="+", default=TARGETS)
    parser.add_argument("--episodes", type=int, default=EPISODES)
    parser.add_argument("--seed", type=int, default=SEED)
    args = parser.parse_args()
    if args.episodes < 1:
        raise SystemExit("Error: --episodes must be at least 1")
    code = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    data = {"policy": POLICY, "code_version": code,
            "command": f"PYTHONPATH=src python benchmarks/random_returns.py --out {args.out} --episodes "
                       f"{args.episodes} --seed {args.seed}",
            "targets": {t: random_returns(t, args.episodes, args.seed) for t in args.targets}}
    write_text_atomic(args.out, json.dumps(data, indent=1) + "\n")


if __name__ == "__main__":
    main()
