"""Does a change of numerics change learning? Paired seeds, two commands that differ in one flag.

    python benchmarks/paired_numerics.py --seeds 2-11 --mark 300000 [--out FILE.json] \\
        [--a=--compile] [--b=--no-compile] [--base "teacher train hopper --steps 2000000"] [--lanes 1]

For each seed, runs `mikt BASE --seed S A` and `mikt BASE --seed S B` one after the other (with `--lanes N`, N
seeds at once, one process per lane: what a run learns does not depend on its speed, so lanes change the
wall-clock time only; never more lanes than cores),
each stopped (SIGTERM: the run stays resumable) once its metrics pass the mark, and reads the mean return of
the last 100 training episodes at the mark. The budget stays BASE's (2M), so the LR and any schedule are those
of a 2M run read at the mark, not of a run whose budget is the mark. Prints per-seed returns, the paired
difference (mean ± sample std), the count of seeds where A is lower, and the paired Wilcoxon signed-rank p.

One seed cannot tell two numeric paths apart (issue 48: five seeds in a row came out lower for the compiled
path by chance, p = 0.85 over ten): use ten or more. Run it on a quiet machine; it takes ~2 × seeds × mark /
(1,000 steps/s).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from scipy.stats import wilcoxon


def seeds_of(text: str) -> list[int]:
    first, _, last = text.partition("-")
    return list(range(int(first), int(last or first) + 1))


def return_at_mark(base: str, flag: str, seed: int, mark: int) -> float:
    """Train until the metrics pass `mark`, stop the run, and read its return there."""
    with tempfile.TemporaryDirectory() as registry:
        env = {**os.environ, "MIKT_REGISTRY": registry}
        cmd = [sys.executable, "-m", "miktcli", *shlex.split(base), "--seed", str(seed), *shlex.split(flag)]
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        metrics = Path(registry) / "runs" / "run1" / "metrics.jsonl"
        try:
            while proc.poll() is None:
                time.sleep(2)
                rows = [json.loads(line) for line in metrics.read_text().splitlines()] if metrics.exists() else []
                passed = [r for r in rows if r["steps"] >= mark]
                if passed:
                    proc.send_signal(signal.SIGTERM)
                    proc.wait(timeout=120)
                    return float(passed[0]["return_mean"])
        finally:
            if proc.poll() is None:
                proc.kill()
        raise SystemExit(f"{' '.join(cmd)} ended (exit {proc.returncode}) before step {mark:,}")


def commit() -> str:
    """The code's commit, with "+changes" when the work tree differs from it."""
    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+changes" if dirty else "")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="2-11")
    parser.add_argument("--mark", type=int, default=300_000)
    parser.add_argument("--base", default="teacher train hopper --steps 2000000")
    parser.add_argument("--a", default="--compile")
    parser.add_argument("--b", default="--no-compile")
    parser.add_argument("--out", type=Path)
    parser.add_argument("--lanes", type=int, default=1, help="seeds trained at once (each A then B)")
    args = parser.parse_args()

    def paired(seed: int) -> dict:
        a, b = (return_at_mark(args.base, flag, seed, args.mark) for flag in (args.a, args.b))
        print(f"seed {seed}: {args.a} {a:,.0f}  {args.b} {b:,.0f}", file=sys.stderr)
        return {"seed": seed, "a": a, "b": b}

    with ThreadPoolExecutor(max_workers=max(1, args.lanes)) as lanes:
        rows = list(lanes.map(paired, seeds_of(args.seeds)))
    diffs = [r["a"] - r["b"] for r in rows]
    summary = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "command": " ".join(sys.argv),
        "commit": commit(), "a": args.a, "b": args.b,
        "mark": args.mark, "rows": rows,
        "mean_a": statistics.mean(r["a"] for r in rows), "mean_b": statistics.mean(r["b"] for r in rows),
        "paired_difference_mean": statistics.mean(diffs),
        "paired_difference_std": statistics.stdev(diffs) if len(diffs) > 1 else float("nan"),
        "a_lower_on": sum(d < 0 for d in diffs),
        "wilcoxon_p": float(wilcoxon(diffs).pvalue) if len(diffs) > 1 and any(diffs) else float("nan"),
    }
    text = json.dumps(summary, indent=1)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
