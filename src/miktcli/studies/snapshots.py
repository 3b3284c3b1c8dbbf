"""A study's runs, copied into its results folder to commit or carry, and back into a registry.

A registry's run folders also hold checkpoints and students (large, and not needed to read the results).
`snapshot` copies `run.json` and `metrics.jsonl` of every completed run named in `RESULTS/state.json` into
`RESULTS/runs/RUN/`, enough for the report to regenerate from a fresh clone. Unfinished cells are listed,
not copied.

With `in_flight` (the study stopped: a run a live process trains is refused), the cells still training are
kept too: `RESULTS/in-flight/RUN/` gets their last checkpoint (~1.1 MB), metrics and card, so that a session
ending on one machine does not throw away hours of a 2M-step run when the next starts on another. That
folder is built beside the old one and swapped in whole; a plain snapshot drops the in-flight copy of a run
it finds completed.

`restore` goes the other way, for a fresh clone or another machine: every snapshot whose run folder the
registry lacks is copied back, so the study skips those finished cells (instead of training them again) and
its report includes them; an in-flight snapshot comes back as the interrupted run it was, which the study
resumes from its checkpoint; other cells leave state.json and start afresh under new ids. It refuses, before
copying anything, when the registry holds other runs under the snapshots' ids. A restored finished run has
no checkpoint or student file, so `mikt eval` says it cannot evaluate it.
"""

from __future__ import annotations

import contextlib
import json
import shutil
from pathlib import Path
from typing import NamedTuple

from miktcli.errors import MiktError
from miktcli.registry.files import write_bytes_atomic, write_text_atomic
from miktcli.registry.runs import lock_owner, open_run, runs_dir
from miktcli.studies.state import by_run_number
from miktcli.studies.state import read_state as read_state_file

IN_FLIGHT = "in-flight"
IN_FLIGHT_FILES = ("checkpoint.safetensors", "metrics.jsonl", "run.json")  # the card last, as a run writes it
FINISHED_FILES = ("metrics.jsonl", "run.json")


class Copied(NamedTuple):
    """What happened to one cell's run."""

    run_id: str
    cell: str
    what: str  # e.g. "completed, copied", "training, 1,234/2,000 steps", "restored (in flight: resumes)"


def read_state(results: Path) -> dict[str, str]:
    """The cell → run id map of a results folder's state.json; a folder without one is no study."""
    path = results / "state.json"
    if not path.is_file():
        raise MiktError(f"{results} holds no study (no state.json)", hint="name the study's results folder (--out)")
    return read_state_file(path)


def snapshot(results: Path, registry: Path, in_flight: bool = False) -> list[Copied]:
    """Copy every completed run (and with `in_flight` every unfinished run's checkpoint) into `results`."""
    state = read_state(results)
    copied = _snapshot_in_flight(results, registry, state) if in_flight else []
    for cell, run_id in by_run_number(state):
        source = runs_dir(registry) / run_id
        if not (source / "run.json").is_file():
            copied.append(Copied(run_id, cell, f"not in {registry}"))
            continue
        card = open_run(registry, run_id).card
        if card.status != "completed":
            copied.append(Copied(run_id, cell, f"{card.status}, {card.steps_done:,}/{card.total_steps:,} steps"))
            continue
        _copy_files(source, results / "runs" / run_id, FINISHED_FILES)
        shutil.rmtree(results / IN_FLIGHT / run_id, ignore_errors=True)  # superseded by the finished run
        copied.append(Copied(run_id, cell, "completed, copied"))
    with contextlib.suppress(OSError):  # the last in-flight run finished: no empty folder left to puzzle over
        (results / IN_FLIGHT).rmdir()
    return copied


def _copy_files(source: Path, target: Path, names: tuple[str, ...]) -> None:
    for name in names:  # in order, each whole: the card last, so it never describes files that are not there
        write_bytes_atomic(target / name, (source / name).read_bytes())


def _read_json(path: Path, what: str) -> object:
    try:
        return json.loads(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as err:
        raise MiktError(f"{path}: damaged {what}: {type(err).__name__}: {err}") from None


def _snapshot_in_flight(results: Path, registry: Path, state: dict[str, str]) -> list[Copied]:
    """Every unfinished run with a checkpoint into RESULTS/in-flight/, built beside it and swapped in whole."""
    runs, training = [], []
    for cell, run_id in by_run_number(state):
        if not (runs_dir(registry) / run_id / "run.json").is_file():
            continue
        run = open_run(registry, run_id)
        if run.card.status == "completed" or not run.checkpoint_path.is_file():
            continue
        if lock_owner(run) is not None:  # its checkpoint, metrics and card could be copied from different moments
            training.append(run_id)
        runs.append((cell, run))
    if training:
        raise MiktError(f"{', '.join(training)} still training: its checkpoint could change while it is copied",
                        hint="stop the study (Ctrl-C or SIGTERM; it resumes) and snapshot again")
    fresh, old = results / f".{IN_FLIGHT}.new", results / f".{IN_FLIGHT}.old"
    shutil.rmtree(fresh, ignore_errors=True)
    fresh.mkdir(parents=True)
    copied = []
    for cell, run in runs:
        _copy_files(run.path, fresh / run.id, IN_FLIGHT_FILES)
        copied.append(Copied(run.id, cell, f"{run.card.status} at {run.card.steps_done:,} steps, checkpoint kept"))
    current = results / IN_FLIGHT
    if current.exists():
        current.rename(old)
    fresh.rename(current)
    shutil.rmtree(old, ignore_errors=True)
    return copied


def _same_run(a: dict, b: dict) -> bool:
    return all(a.get(k) == b.get(k) for k in ("run_id", "created", "env", "method", "seed"))


def restore(results: Path, registry: Path) -> list[Copied]:
    """Snapshots back into the registry; cells without one leave state.json (they start afresh, under new
    run ids, instead of adopting whatever run later takes their old id)."""
    state = read_state(results)
    plan, conflicts = [], []
    for cell, run_id in by_run_number(state):
        snap, files = results / "runs" / run_id, FINISHED_FILES
        if not (snap / "run.json").is_file():
            snap, files = results / IN_FLIGHT / run_id, IN_FLIGHT_FILES
        if not (snap / "run.json").is_file():
            plan.append((cell, run_id, None, files))
            continue
        target = runs_dir(registry) / run_id / "run.json"
        if target.is_file() and not _same_run(_read_json(snap / "run.json", "run card"),
                                              _read_json(target, "run card")):
            conflicts.append(f"{run_id} ({cell})")
        plan.append((cell, run_id, snap, files))
    if conflicts:  # refused before anything is copied
        raise MiktError(f"{registry} already has other runs under these ids: {', '.join(conflicts)}",
                        hint="restore into an empty registry (--registry) or move those runs away")
    kept, copied = {}, []
    for cell, run_id, snap, files in plan:
        if snap is None:
            copied.append(Copied(run_id, cell, "no snapshot (unfinished): starts afresh"))
            continue
        target = runs_dir(registry) / run_id
        if (target / "run.json").is_file():
            copied.append(Copied(run_id, cell, f"already in {registry}"))
        else:
            _copy_files(snap, target, files)
            copied.append(Copied(run_id, cell, "restored" + (" (in flight: resumes)" if snap.parent.name == IN_FLIGHT
                                                             else "")))
        kept[cell] = run_id
    write_text_atomic(results / "state.json", json.dumps(kept, indent=2, ensure_ascii=False))
    return copied
