"""Copies the card and metrics of every finished cell of a study into its results folder, for committing.

    python benchmarks/snapshot_study.py benchmarks/results/paper-2m/paper-2m [--registry registry]
                                        [--in-flight] [--restore]

The registry's run folders also hold checkpoints and students (large, and not needed to read the results);
`RESULTS/runs/RUN/` gets `run.json` and `metrics.jsonl` of each completed run named in `RESULTS/state.json`.
Unfinished cells are listed, not copied.

`--in-flight`, with the study stopped (SIGTERM; it refuses runs a live process trains), also keeps the cells
still training: `RESULTS/in-flight/RUN/` gets their last checkpoint (~1.1 MB), metrics and card, so that a
session ending on one machine does not throw away hours of a 2M-step run when the next starts on another.
`RESULTS/in-flight/` is rewritten whole each time; a plain snapshot drops the in-flight copy of a run it
finds completed.

`--restore` goes the other way, for a fresh clone or another machine: every snapshot whose run folder the
registry lacks is copied back, so the study skips those finished cells (instead of training them again) and
its report includes them; an in-flight snapshot comes back as the interrupted run it was, which the study
resumes from its checkpoint; other cells leave state.json and start afresh under new ids. Run it before the
study starts there. It refuses when the registry holds other runs under the snapshots' ids. A restored
finished run has no checkpoint or student file, so `mikt eval` says it cannot evaluate it.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

from miktcli.registry.files import write_text_atomic
from miktcli.registry.runs import lock_owner, open_run

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path)
    parser.add_argument("--registry", type=Path, default=ROOT / "registry")
    parser.add_argument("--in-flight", action="store_true",
                        help="also keep unfinished runs' checkpoints (the study must be stopped)")
    parser.add_argument("--restore", action="store_true", help="copy snapshots back into a registry lacking them")
    args = parser.parse_args()
    state = json.loads((args.results / "state.json").read_text())
    if args.restore:
        restore(args.results, args.registry, state)
        return
    if args.in_flight:
        snapshot_in_flight(args.results, args.registry, state)
    for cell, run_id in by_run_number(state):
        source = args.registry / "runs" / run_id
        if not (source / "run.json").is_file():
            print(f"{run_id}  {cell}: not in {args.registry}")
            continue
        card = json.loads((source / "run.json").read_text())
        if card["status"] != "completed":
            print(f"{run_id}  {cell}: {card['status']}, {card['steps_done']:,}/{card['total_steps']:,} steps")
            continue
        target = args.results / "runs" / run_id
        target.mkdir(parents=True, exist_ok=True)
        for name in ("run.json", "metrics.jsonl"):
            shutil.copy(source / name, target / name)
        shutil.rmtree(args.results / IN_FLIGHT / run_id, ignore_errors=True)  # superseded by the finished run
        print(f"{run_id}  {cell}: completed, copied")


def by_run_number(state: dict[str, str]) -> list[tuple[str, str]]:
    """The cells in the order their runs were created (run9 before run10)."""
    return sorted(state.items(), key=lambda cell_run: int(cell_run[1].removeprefix("run")))


IN_FLIGHT = "in-flight"
IN_FLIGHT_FILES = ("checkpoint.safetensors", "metrics.jsonl", "run.json")  # the card last, as a run writes it


def snapshot_in_flight(results: Path, registry: Path, state: dict[str, str]) -> None:
    """Every unfinished run with a checkpoint into RESULTS/in-flight/, built beside it and swapped in whole."""
    fresh = results / f".{IN_FLIGHT}.new"
    shutil.rmtree(fresh, ignore_errors=True)
    fresh.mkdir(parents=True)
    training = []
    for cell, run_id in by_run_number(state):
        source = registry / "runs" / run_id
        if not (source / "run.json").is_file():
            continue
        run = open_run(registry, run_id)
        if run.card.status == "completed" or not run.checkpoint_path.is_file():
            continue
        if lock_owner(run) is not None:  # its checkpoint, metrics and card could be copied from different moments
            training.append(run_id)
            continue
        (fresh / run_id).mkdir()
        for name in IN_FLIGHT_FILES:
            shutil.copy(source / name, fresh / run_id / name)
        print(f"{run_id}  {cell}: {run.card.status} at {run.card.steps_done:,} steps, checkpoint kept")
    if training:
        shutil.rmtree(fresh)
        raise SystemExit(f"error: {', '.join(training)} still training: stop the study (SIGTERM) first")
    old = results / IN_FLIGHT
    if old.exists():
        old.rename(results / f".{IN_FLIGHT}.old")
    fresh.rename(old)
    shutil.rmtree(results / f".{IN_FLIGHT}.old", ignore_errors=True)


def same_run(a: dict, b: dict) -> bool:
    return all(a.get(k) == b.get(k) for k in ("run_id", "created", "env", "method", "seed"))


def restore(results: Path, registry: Path, state: dict[str, str]) -> None:
    """Snapshots back into the registry; cells without one leave state.json (they start afresh, under new
    run ids, instead of adopting whatever run later takes their old id)."""
    kept, conflicts = {}, []
    for cell, run_id in by_run_number(state):
        snapshot, target = results / "runs" / run_id, registry / "runs" / run_id
        files = ("metrics.jsonl", "run.json")
        if not (snapshot / "run.json").is_file():
            snapshot, files = results / IN_FLIGHT / run_id, IN_FLIGHT_FILES
        if not (snapshot / "run.json").is_file():
            print(f"{run_id}  {cell}: no snapshot (unfinished): starts afresh")
            continue
        card = json.loads((snapshot / "run.json").read_text())
        if (target / "run.json").is_file():
            if not same_run(card, json.loads((target / "run.json").read_text())):
                conflicts.append(f"{run_id} ({cell})")
                continue
            print(f"{run_id}  {cell}: already in {registry}")
        else:
            target.mkdir(parents=True, exist_ok=True)
            for name in files:  # the card last: it never describes missing metrics
                shutil.copy(snapshot / name, target / name)
            print(f"{run_id}  {cell}: restored" + (" (in flight: resumes)" if snapshot.parent.name == IN_FLIGHT
                                                   else ""))
        kept[cell] = run_id
    if conflicts:
        raise SystemExit(f"error: {registry} already has other runs under these ids: {', '.join(conflicts)}; "
                         "restore into an empty registry (--registry) or move those runs away")
    write_text_atomic(results / "state.json", json.dumps(kept, indent=2, ensure_ascii=False))


if __name__ == "__main__":
    main()
