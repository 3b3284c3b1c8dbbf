"""How steady each run's update time stayed, phase by phase: the check of issue 48's "no run may slow as it trains".

    python benchmarks/update_steadiness.py RUNS_DIR [RUNS_DIR ...] [--json OUT]

RUNS_DIR is a registry's `runs/` folder or a study's snapshot `runs/` (each run a folder with run.json and
metrics.jsonl); only completed runs are read. The measure is the one training flags a slowdown by
(miktcli.workflows.slowdown): the update's time over the rollout's in each iteration, so that a busy machine
cancels out, its rolling median over 20 iterations, and per phase of the schedule the highest of those medians
over the lowest. The slowed multi-cat runs reached 2.4-3.1x in their first phase, the others at most 1.57x;
training flags 2x.
"""

from __future__ import annotations

import argparse
import json
import statistics
from collections.abc import Callable
from pathlib import Path

from miktcli.engine.ppo import PPOConfig
from miktcli.methods.mikt import MiktConfig
from miktcli.workflows.slowdown import FACTOR, WINDOW, update_ratio


def phases_of(card: dict) -> Callable[[int], str]:
    """The schedule's phase of an iteration (1-based), as training named it (its session's `_phase_of`)."""
    options = (card.get("config") or {}).get("options")
    if card.get("method") != "mikt" or not options:
        return lambda _iteration: "train"
    config = MiktConfig(**options)
    return lambda iteration: config.phase((iteration - 1) / iterations_of(card))


def iterations_of(card: dict) -> int:
    """The run's iteration count as its trainer counted it (PPOTrainer.num_iterations)."""
    return max(1, card["total_steps"] // PPOConfig.from_record(card["config"]["ppo"]).batch_size)


def steadiness(run: Path) -> dict | None:
    card = json.loads((run / "run.json").read_text())
    if card.get("status") != "completed":
        return None
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines() if line.strip()]
    phase_of = phases_of(card)
    ratios: dict[str, list[float]] = {}
    for row in rows[1:]:  # the first iteration's update holds one-off costs (allocation, a compile)
        ratio = update_ratio(row)
        if ratio > 0:
            ratios.setdefault(phase_of(row["iteration"]), []).append(ratio)
    spread = {}
    for phase, values in ratios.items():
        medians = [statistics.median(values[i - WINDOW:i]) for i in range(WINDOW, len(values) + 1)]
        if medians:
            spread[phase] = round(max(medians) / min(medians), 2)
    return {"run": card["run_id"], "env": card["env"], "method": card["method"], "seed": card["seed"],
            "teachers": [f"{t['name']}@v{t['version']}" for t in card.get("teachers") or []],
            "spread": spread, "flagged": (card.get("result") or {}).get("slowdowns", [])}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs_dirs", nargs="+", type=Path)
    parser.add_argument("--json", type=Path, help="write the table as JSON here too")
    args = parser.parse_args()
    results = [r for d in args.runs_dirs for p in sorted(d.iterdir(), key=lambda p: (len(p.name), p.name))
               if (p / "run.json").is_file() and (r := steadiness(p)) is not None]
    phases = list(dict.fromkeys(ph for r in results for ph in r["spread"]))
    print(f"rolling median ({WINDOW} iterations) of update / rollout time: highest over lowest, per phase "
          f"(training flags {FACTOR:g}x)\n")
    print("| run | teachers > target | method | seed | " + " | ".join(phases) + " | flagged |")
    print("|---|---|---|---|" + "---|" * len(phases) + "---|")
    for r in results:
        cells = [f"{r['spread'][ph]:.2f}x" if ph in r["spread"] else "-" for ph in phases]
        print(f"| {r['run']} | {'+'.join(r['teachers']) or '-'} > {r['env']} | {r['method']} | {r['seed']} | "
              + " | ".join(cells) + f" | {len(r['flagged']) or 'no'} |")
    worst = max((v for r in results for v in r["spread"].values()), default=float("nan"))
    print(f"\n{len(results)} completed runs; highest spread {worst:.2f}x; "
          f"{sum(bool(r['flagged']) for r in results)} flagged by training")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
