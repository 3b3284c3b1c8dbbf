"""Trains the shipped teachers with the paper's settings, one after another, resumably.

    python benchmarks/train_teachers.py            # all of them, in this order
    python benchmarks/train_teachers.py hopper     # just one

Each teacher is `mikt teacher train ENV --steps N --seed S`; a run that was interrupted is resumed with
`--resume`, a finished one is skipped. Learning curves are copied to benchmarks/results/teachers/v2/ (the
teachers of mikt 0.2: raw actions, the paper's 2M budget; v1's curves stay in benchmarks/results/teachers/).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REGISTRY = Path(os.environ.get("MIKT_REGISTRY", ROOT / "registry"))
RESULTS = Path(os.environ.get("MIKT_RESULTS", ROOT / "benchmarks" / "results")) / "teachers" / "v2"
STEPS = 2_000_896  # the paper's 2M, as whole 2048-step rollouts (what `--steps 2000000` trains)
JOBS = [  # (env, steps, seed), in the order the paper-scale study needs them
    ("centipede-four", STEPS, 0),
    ("centipede-six", STEPS, 0),
    ("ant", STEPS, 0),
    ("hopper", STEPS, 0),
]


def find_run(env: str, steps: int, seed: int) -> dict | None:
    for card_path in sorted((REGISTRY / "runs").glob("run*/run.json")):
        card = json.loads(card_path.read_text())
        if (card["kind"], card["env"], card["total_steps"], card["seed"]) == ("teacher", env, steps, seed):
            return card
    return None


def main(selected: list[str]) -> None:
    for env, steps, seed in JOBS:
        if selected and env not in selected:
            continue
        card = find_run(env, steps, seed)
        if card and card["status"] == "completed":
            print(f"{env}: done in {card['run_id']} ({card['result'].get('teacher')})", flush=True)
        else:
            args = ["--resume", card["run_id"]] if card else [env, "--steps", str(steps), "--seed", str(seed)]
            cmd = ["mikt", "teacher", "train", *args, "--registry", str(REGISTRY)]
            print("$", " ".join(cmd), flush=True)
            subprocess.run(cmd, check=True)
            card = find_run(env, steps, seed)
        RESULTS.mkdir(parents=True, exist_ok=True)
        run_dir = REGISTRY / "runs" / card["run_id"]
        shutil.copy(run_dir / "metrics.jsonl", RESULTS / f"{env}-metrics.jsonl")
        shutil.copy(run_dir / "run.json", RESULTS / f"{env}-run.json")


if __name__ == "__main__":
    main(sys.argv[1:])
