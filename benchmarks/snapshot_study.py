"""Copies the card and metrics of every finished cell of a study into its results folder, for committing.

    python benchmarks/snapshot_study.py benchmarks/results/paper-2m/paper-2m [--registry registry]

The registry's run folders also hold checkpoints and students (large, and not needed to read the results);
`RESULTS/runs/RUN/` gets `run.json` and `metrics.jsonl` of each completed run named in `RESULTS/state.json`.
Unfinished cells are listed, not copied.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path)
    parser.add_argument("--registry", type=Path, default=ROOT / "registry")
    args = parser.parse_args()
    state = json.loads((args.results / "state.json").read_text())
    for cell, run_id in sorted(state.items(), key=lambda kv: int(kv[1][3:])):
        source = args.registry / "runs" / run_id
        card = json.loads((source / "run.json").read_text())
        if card["status"] != "completed":
            print(f"{run_id}  {cell}: {card['status']}, {card['steps_done']:,}/{card['total_steps']:,} steps")
            continue
        target = args.results / "runs" / run_id
        target.mkdir(parents=True, exist_ok=True)
        for name in ("run.json", "metrics.jsonl"):
            shutil.copy(source / name, target / name)
        print(f"{run_id}  {cell}: completed, copied")


if __name__ == "__main__":
    main()
