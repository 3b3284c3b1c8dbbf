"""Study throughput: cells per hour of the same tiny grid, serial (in process) against Ray with N workers.

    python benchmarks/study_scaling.py --workers 1 2 [--cells 8] [--steps 20480] [--json results/study-scaling.json]

Each configuration trains the same grid (centipede-four from scratch, `--cells` seeds of `--steps` steps) in a
fresh registry, one after another in this process; the table gives wall time, cells per hour, the speed-up
over serial and the efficiency (speed-up / workers). Needs `pip install -e .[ray]`. Measure on a quiet machine.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def grid_text(cells: int, steps: int) -> str:
    return (f'name = "scaling"\nsteps = {steps}\nseeds = {list(range(cells))}\neval_episodes = 1\n'
            '[[pairs]]\nfrom = ["none"]\nto = "centipede-four"\n[[methods]]\nname = "vpg"\nmethod = "vpg"\n')


def timed_study(cells: int, steps: int, workers: int | None) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        grid = Path(tmp) / "grid.toml"
        grid.write_text(grid_text(cells, steps))
        command = [sys.executable, "-m", "miktcli", "study", str(grid), "--out", str(Path(tmp) / "out"),
                   "--registry", str(Path(tmp) / "registry")]
        if workers is not None:
            command += ["--workers", str(workers)]
        start = time.perf_counter()
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                       env={**os.environ, "MIKT_THREADS": "1"})
        return time.perf_counter() - start


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--cells", type=int, default=8)
    parser.add_argument("--steps", type=int, default=20_480)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    rows = [{"backend": "serial", "workers": 1, "seconds": timed_study(args.cells, args.steps, None)}]
    for n in args.workers:
        rows.append({"backend": "ray", "workers": n, "seconds": timed_study(args.cells, args.steps, n)})
    serial = rows[0]["seconds"]
    print(f"{args.cells} cells x {args.steps:,} steps (centipede-four, vpg), {platform.node()}, "
          f"{os.cpu_count()} CPUs\n")
    print("| backend | workers | wall time (s) | cells per hour | speed-up | efficiency |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        r["cells_per_hour"] = args.cells * 3600 / r["seconds"]
        r["speedup"] = serial / r["seconds"]
        r["efficiency"] = r["speedup"] / r["workers"]
        print(f"| {r['backend']} | {r['workers']} | {r['seconds']:.0f} | {r['cells_per_hour']:.0f} | "
              f"{r['speedup']:.2f}× | {r['efficiency']:.0%} |")
    if args.json:
        args.json.write_text(json.dumps({"cells": args.cells, "steps": args.steps, "rows": rows}, indent=2))


if __name__ == "__main__":
    main(sys.argv[1:])
