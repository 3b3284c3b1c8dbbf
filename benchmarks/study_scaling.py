"""Study throughput: cells per hour of the same tiny grid, serial (in process) against Ray with N workers.

    python benchmarks/study_scaling.py --workers 1 2 [--cells 8] [--steps 20480] [--json results/study-scaling.json]
    python benchmarks/study_scaling.py --seeds-together 5 --workers 2 [--json results/study-scaling-together.json]

Each configuration trains the same grid (centipede-four from scratch, `--cells` seeds of `--steps` steps) in a
fresh registry, one after another in this process; the table gives wall time, cells per hour, the speed-up
over serial and the efficiency (speed-up / workers). With `--seeds-together S` the grid is PPO from scratch on
centipede-four and centipede-six, S seeds each (two cells of S seeds), trained on Ray with N workers one seed a
task against the same grid with `seeds_together = true` (a cell's seeds one task); the speed-up is over one
seed a task. Needs `pip install -e .[ray]`. Measure on a quiet machine.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

def grid_text(cells: int, steps: int, targets: tuple[str, ...] = ("centipede-four",), together: bool = False,
              teachers: tuple[str, ...] = ()) -> str:
    """The grid: PPO from scratch on each target, or with `teachers` MIKT from them to each target."""
    sources = ", ".join(f'"{t}"' for t in teachers or ("none",))
    pairs = "".join(f'[[pairs]]\nfrom = [{sources}]\nto = "{target}"\n' for target in targets)
    method = "mikt" if teachers else "vpg"
    return (f'name = "scaling"\nsteps = {steps}\nseeds = {list(range(cells))}\neval_episodes = 1\n'
            f'baseline = "{method}"\nseeds_together = {str(together).lower()}\n{pairs}'
            f'[[methods]]\nname = "{method}"\nmethod = "{method}"\n')


def timed_study(text: str, workers: int | None) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        grid = Path(tmp) / "grid.toml"
        grid.write_text(text)
        shutil.copytree(ROOT / "registry" / "teachers", Path(tmp) / "registry" / "teachers")  # the packaged ones
        command = [sys.executable, "-m", "miktcli", "study", str(grid), "--out", str(Path(tmp) / "out"),
                   "--registry", str(Path(tmp) / "registry")]
        if workers is not None:
            command += ["--workers", str(workers)]
        start = time.perf_counter()
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                       env={**os.environ, "MIKT_THREADS": "1"})
        return time.perf_counter() - start


def table(rows: list[dict], base: float, cells: int, efficiency: bool = True) -> None:
    """Print the rows, adding cells per hour, the speed-up over `base` seconds and (over serial) the
    efficiency, speed-up / workers."""
    print("| backend | workers | wall time (s) | cells per hour | speed-up |" + (" efficiency |" if efficiency else ""))
    print("|---|---|---|---|---|" + ("---|" if efficiency else ""))
    for r in rows:
        r["cells_per_hour"] = cells * 3600 / r["seconds"]
        r["speedup"] = base / r["seconds"]
        line = (f"| {r['backend']} | {r['workers']} | {r['seconds']:.0f} | {r['cells_per_hour']:.0f} | "
                f"{r['speedup']:.2f}× |")
        if efficiency:
            r["efficiency"] = r["speedup"] / r["workers"]
            line += f" {r['efficiency']:.0%} |"
        print(line)


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--cells", type=int, default=8)
    parser.add_argument("--steps", type=int, default=20_480)
    parser.add_argument("--seeds-together", type=int, default=None, metavar="S",
                        help="two targets x S seeds, one seed a task against a cell's seeds a task")
    parser.add_argument("--from", dest="teachers", action="append", default=[],
                        help="with --seeds-together: MIKT from these teachers (give it twice for two) to "
                        "centipede-eight and cp-centipede-eight, instead of PPO on centipede-four and -six")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    when = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    if args.seeds_together is not None:
        seeds, teachers = args.seeds_together, tuple(args.teachers)
        targets = ("centipede-eight", "cp-centipede-eight") if teachers else ("centipede-four", "centipede-six")
        rows = []
        for n in args.workers:
            for together in (False, True):
                rows.append({"backend": "ray, a cell's seeds a task" if together else "ray, one seed a task",
                             "workers": n, "seeds_together": together,
                             "seconds": timed_study(grid_text(seeds, args.steps, targets, together, teachers), n)})
        what = f"mikt from {' + '.join(teachers)}" if teachers else "vpg"
        print(f"{len(targets)} targets x {seeds} seeds x {args.steps:,} steps ({what} on {' and '.join(targets)}), "
              f"{platform.node()}, {os.cpu_count()} CPUs, {when}\n")
        table(rows, rows[0]["seconds"], len(targets) * seeds, efficiency=False)
        record = {"measured": when, "method": "mikt" if teachers else "vpg", "teachers": list(teachers),
                  "targets": list(targets), "seeds": seeds, "steps": args.steps, "rows": rows}
    else:
        rows = [{"backend": "serial", "workers": 1, "seconds": timed_study(grid_text(args.cells, args.steps), None)}]
        for n in args.workers:
            rows.append({"backend": "ray", "workers": n, "seconds": timed_study(grid_text(args.cells, args.steps), n)})
        print(f"{args.cells} cells x {args.steps:,} steps (centipede-four, vpg), {platform.node()}, "
              f"{os.cpu_count()} CPUs, {when}\n")
        table(rows, rows[0]["seconds"], args.cells)
        record = {"cells": args.cells, "steps": args.steps, "rows": rows}
    if args.json:
        args.json.write_text(json.dumps(record, indent=2))


if __name__ == "__main__":
    main(sys.argv[1:])
