"""Run folders: registry/runs/runN/ with run.json (RunCard), metrics.jsonl and checkpoints.

Every `teacher train` and `transfer` is a run. Checkpoints hold the complete training state (weights,
optimiser moments, normaliser and reward statistics, RNG states), so an interrupted run resumes.
"""

from __future__ import annotations

import json
import math
import re
import shutil
from pathlib import Path
from typing import Any

import torch
from pydantic import BaseModel, ConfigDict, ValidationError

from miktcli import limits
from miktcli.errors import MiktError, describe_validation_error
from miktcli.registry import location
from miktcli.registry.cards import RUN_SCHEMA_VERSION, RunCard, now
from miktcli.registry.files import (
    append_line,
    read_card,
    read_tensors,
    save_with_card,
    tensors_sha256,
    verify_sha,
    write_bytes_atomic,
    write_text_atomic,
)
from miktcli.registry.locks import FileLock, lock_holder
from miktcli.registry.tensorboard import EVENTS_FILE, append_event, event_records

RUN_RE = re.compile(r"^run(\d+)$")
RUN_TARGET_RE = re.compile(r"^(run\d+|last)$")  # what eval and inspect accept as a run
CHECKPOINT_SCHEMA_VERSION = 3  # 2, 3: the run card it carries may be a version-2 or version-3 run card


class CheckpointCard(BaseModel):
    model_config = ConfigDict(extra="forbid")

    schema_version: int = CHECKPOINT_SCHEMA_VERSION
    run_id: str
    iteration: int
    steps: int
    progress: dict[str, Any]
    tensors_sha256: str
    run: RunCard | None = None  # the run's card when the checkpoint was written: the file describes itself


def runs_dir(registry: Path) -> Path:
    return Path(registry) / "runs"


def check_registry(registry: Path) -> None:
    """A registry is a folder (or not there yet); a file in its place is a mistake worth naming."""
    if Path(registry).exists() and not Path(registry).is_dir():
        raise MiktError(f"registry {registry} is a file, not a folder",
                        hint="point --registry or MIKT_REGISTRY at a folder")


def run_number(run_id: str) -> int:
    """The order runs were created in: run9 is 9, before run10 (0 for an id that is not a run's)."""
    m = RUN_RE.fullmatch(run_id)
    return int(m.group(1)) if m else 0


def run_ids(registry: Path) -> list[str]:
    check_registry(registry)
    root = runs_dir(registry)
    if not root.is_dir():
        return []
    found = [(int(m.group(1)), p.name) for p in root.iterdir() if (m := RUN_RE.fullmatch(p.name)) and p.is_dir()]
    return [name for _, name in sorted(found)]


def _json_safe(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None  # JSON has no NaN; a missing mean (no episode finished yet) becomes null
    return value


class RunLock:
    """An exclusive OS lock on runN/lock, held while a process trains the run (registry.locks).

    A run whose card says `running` but whose lock is free has lost its trainer: `stale`."""

    def __init__(self, run: Run):
        self.run, self.path = run, run.path / "lock"
        self.lock = FileLock(self.path)

    def acquire(self) -> RunLock:
        if not self.lock.try_acquire():
            owner = lock_owner(self.run)
            raise MiktError(f"{self.run.id} is being trained by pid {owner if owner else '?'}",
                            hint="wait for it, or stop that process (Ctrl-C or SIGTERM) and resume")
        return self

    def release(self) -> None:
        self.lock.release()


def lock_owner(run: Run) -> int | None:
    """The pid training `run` now, or None when no live process holds its lock."""
    return lock_holder(run.path / "lock")


class Run:
    def __init__(self, path: Path, card: RunCard):
        self.path, self.card = path, card
        self.damaged_metric_lines = 0  # counted by read_metrics

    @property
    def status(self) -> str:
        """The card's status, with what the run's lock adds: a created run is `queued` while a process holds
        it (a study on Ray waiting for a free worker) and `not started` otherwise; a run marked running that
        no process holds is `stale` (its trainer is gone: SIGKILL, crash), or `not started` when it has no
        checkpoint (before the `created` status, prepared cells were marked running)."""
        if self.card.status == "created":
            return "queued" if lock_owner(self) is not None else "not started"
        if self.card.status == "running" and lock_owner(self) is None:
            return "stale" if self.checkpoint_path.exists() else "not started"
        return self.card.status

    @property
    def id(self) -> str:
        return self.card.run_id

    @property
    def metrics_path(self) -> Path:
        return self.path / "metrics.jsonl"

    @property
    def checkpoint_path(self) -> Path:
        return self.path / "checkpoint.safetensors"

    @property
    def student_path(self) -> Path:
        """A finished transfer's teacher-free student (a policy file in the teacher format)."""
        return self.path / "student.safetensors"

    def save_card(self, **updates: Any) -> None:
        # Stamped with this code's version: the card may now hold fields an older card could not.
        self.card = self.card.model_copy(update={**updates, "updated": now(), "schema_version": RUN_SCHEMA_VERSION})
        write_text_atomic(self.path / "run.json", self.card.model_dump_json(indent=2))

    @property
    def events_path(self) -> Path:
        """TensorBoard's view of metrics.jsonl (`tensorboard --logdir registry/runs`)."""
        return self.path / EVENTS_FILE

    def append_metrics(self, metrics: dict[str, Any]) -> None:
        append_line(self.metrics_path, json.dumps({k: _json_safe(v) for k, v in metrics.items()}))
        append_event(self.events_path, metrics)

    def read_metrics(self) -> list[dict[str, Any]]:
        """Every well-formed row, in order. A damaged line (cut by a crash, edited, not UTF-8, not an object
        with integer `iteration` and `steps`) is skipped and counted in `damaged_metric_lines`."""
        self.damaged_metric_lines = 0
        if not self.metrics_path.exists():
            return []
        rows = []
        lines = limits.read_lines_bounded(self.metrics_path, str(self.metrics_path), limits.MAX_METRICS_BYTES,
                                          limits.MAX_METRICS_LINE_BYTES)
        for line in lines:
            try:
                row = json.loads(line.decode("utf-8"))
            except (UnicodeDecodeError, json.JSONDecodeError, RecursionError):  # deep nesting: damaged too
                row = None
            if not (isinstance(row, dict) and all(isinstance(row.get(k), int) for k in ("iteration", "steps"))
                    and all(v is None or isinstance(v, int | float) for v in row.values())):
                self.damaged_metric_lines += bool(line.strip())
                continue
            rows.append(row)
        return rows

    def truncate_metrics(self, iteration: int) -> None:
        """Drop rows newer than the checkpoint being resumed, so the curve has no duplicates."""
        self.write_metrics([r for r in self.read_metrics() if r.get("iteration", 0) <= iteration])

    def write_metrics(self, rows: list[dict[str, Any]]) -> None:
        """Replace the metrics (and their TensorBoard view) with `rows`."""
        write_text_atomic(self.metrics_path, "".join(json.dumps(r) + "\n" for r in rows))
        write_bytes_atomic(self.events_path, event_records(rows))

    def save_checkpoint(self, tensors: dict[str, torch.Tensor], iteration: int, steps: int,
                        progress: dict[str, Any], path: Path | None = None) -> None:
        card = CheckpointCard(run_id=self.id, iteration=iteration, steps=steps, progress=progress,
                              tensors_sha256=tensors_sha256(tensors), run=self.card)
        save_with_card(path or self.checkpoint_path, tensors, card)

    def kept_checkpoint_path(self, name: str) -> Path:
        """A checkpoint kept at a named point of training (e.g. `before-teacher-free`, just before the drop)."""
        return self.path / f"checkpoint-{name}.safetensors"

    def kept_checkpoints(self) -> list[str]:
        return sorted(p.name[len("checkpoint-"):-len(".safetensors")]
                      for p in self.path.glob("checkpoint-*.safetensors"))

    def keep_checkpoint(self, name: str) -> None:
        """Copy the last checkpoint to `kept_checkpoint_path(name)` (atomically: a reader sees the old file or
        the new one, never part of it)."""
        write_bytes_atomic(self.kept_checkpoint_path(name), self.checkpoint_path.read_bytes())

    def load_checkpoint(self, path: Path | None = None) -> tuple[CheckpointCard, dict[str, torch.Tensor]]:
        path = path or self.checkpoint_path
        if not path.exists():
            raise MiktError(f"run '{self.id}' has no checkpoint yet ({path.name})")
        card = read_card(path, CheckpointCard, CHECKPOINT_SCHEMA_VERSION)
        if card.run_id != self.id:  # copied in from another run: its weights would not be this run's
            raise MiktError(f"{path}: the checkpoint belongs to {card.run_id}, not to {self.id}",
                            hint=f"copy {card.run_id}'s whole folder instead, or resume {card.run_id}")
        tensors = read_tensors(path)
        verify_sha(path, tensors, card.tensors_sha256)
        return card, tensors


_last_created: dict[Path, int] = {}  # runs folder → the number of the run this process created last there


def create_run(registry: Path, **fields: Any) -> Run:
    """Allocate the next runN atomically (mkdir fails if another process took it)."""
    root = runs_dir(registry)
    root.mkdir(parents=True, exist_ok=True)
    # The folder this process created last, while it is still there: listing the registry for every new run
    # made preparing a study's N cells quadratic in N. Another process's newer runs only cost a retry each.
    number = _last_created.get(root.resolve())
    if number is None or not (root / f"run{number}").is_dir():
        ids = run_ids(registry)
        number = int(ids[-1][3:]) if ids else 0
    while True:
        number += 1
        path = root / f"run{number}"
        try:
            path.mkdir()
            break
        except FileExistsError:
            continue
    _last_created[root.resolve()] = number
    stamp = now()
    try:
        run = Run(path, RunCard(run_id=path.name, status="created", created=stamp, updated=stamp, **fields))
        run.save_card()
    except BaseException as err:  # a full disk, Ctrl-C: no folder without its card is left behind
        shutil.rmtree(path, ignore_errors=True)
        if isinstance(err, OSError):
            raise MiktError(f"cannot create {path}: {err.strerror or err}",
                            hint="free some space or choose another --registry") from err
        raise
    return run


def open_run(registry: Path, run_id: str) -> Run:
    """Open runN; `last` names the newest run."""
    if run_id == "last":
        ids = run_ids(registry)
        if not ids:
            raise MiktError(f"no runs yet in registry {location.describe(registry)}", hint=location.HINT)
        run_id = ids[-1]
    check_registry(registry)
    path = runs_dir(registry) / run_id
    card_path = path / "run.json"
    if not card_path.is_file():
        if path.is_dir():
            raise MiktError(f"{card_path} is missing: the folder is not a readable run",
                            hint="restore run.json from a backup, or remove the folder")
        known = ", ".join(run_ids(registry)) or "(none)"
        raise MiktError(f"unknown run '{run_id}' in registry {location.describe(registry)}; known: {known}",
                        hint=location.HINT)
    try:
        raw = json.loads(card_path.read_bytes().decode("utf-8"))
    except UnicodeDecodeError:
        raise MiktError(f"{card_path}: not a text file (not UTF-8): damaged") from None
    except (json.JSONDecodeError, RecursionError) as err:
        raise MiktError(f"{card_path}: not valid JSON: {type(err).__name__}: {err}") from None
    found = raw.get("schema_version") if isinstance(raw, dict) else None
    if isinstance(found, int) and found > RUN_SCHEMA_VERSION:
        raise MiktError(f"{card_path}: run card schema version {found} is newer than this mikt understands "
                        f"({RUN_SCHEMA_VERSION})", hint="upgrade mikt to read it")
    try:
        card = RunCard.model_validate(raw)
    except ValidationError as err:
        raise MiktError(f"{card_path}: invalid run card, {describe_validation_error(err)}") from err
    if card.run_id != path.name:  # a folder copied or renamed by hand: its checkpoints name the other run
        raise MiktError(f"{card_path}: the card names {card.run_id} but lives in {path.name}",
                        hint=f"rename the folder back to {card.run_id}")
    return Run(path, card)


def open_resumable(registry: Path, run_id: str, kind: str) -> Run:
    """A run that `--resume` may continue: of the right kind and not finished."""
    run = open_run(registry, run_id)
    if run.card.kind != kind:
        command = "mikt transfer --resume" if run.card.kind == "transfer" else "mikt teacher train --resume"
        raise MiktError(f"run '{run.id}' is a {run.card.kind} run; resume it with `{command}`")
    if run.card.status == "completed":
        raise MiktError(f"run '{run.id}' already completed")
    return run


def list_runs(registry: Path) -> tuple[list[Run], list[tuple[str, MiktError]]]:
    """The readable runs, and (run id, what is wrong) for each run folder whose run.json is not."""
    runs, damaged = [], []
    for run_id in run_ids(registry):
        try:
            runs.append(open_run(registry, run_id))
        except MiktError as err:
            damaged.append((run_id, err))
    return runs, damaged
