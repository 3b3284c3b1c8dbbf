"""How a study's cells get trained: one event type, one executor protocol, one driver.

The driver (`Driver`) prepares the study's cells (studies.study: run folders, state.json, teacher pins),
hands the unfinished ones to an executor, refreshes the report after every cell that ends, and yields one
`CellEvent` per change a user should see. An executor only trains prepared cells:

- `studies.serial.SerialExecutor`: one after another in this process (a cell's seeds together when the
  grid says `seeds_together`);
- `studies.ray_executor.RayExecutor`: in parallel on a local Ray instance or a cluster, in chunks (a cell's
  seeds together in one task when the grid says `seeds_together`).

A new backend implements `Executor` (a `session()` to hold around preparing and training, and `run()`), and
nothing else changes: the CLI, the report and the resume logic stay the same.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from miktcli.errors import MiktError
from miktcli.registry.runs import Run, run_number
from miktcli.studies.grid import Grid
from miktcli.studies.report import Report
from miktcli.studies.study import Study
from miktcli.workflows.together import mark_together

# A cell's states, in the order a cell passes them: `done` (completed before this session), `queued`,
# `training` (started or resumed), `retrying` (its worker died; sent again), then `completed` or `failed`.
STATES = ("done", "queued", "training", "retrying", "completed", "failed")
ENDED = ("completed", "failed")


@dataclass
class CellEvent:
    """One cell as it stands: which run holds it, where its training is, and why it failed if it did."""

    key: str
    run_id: str
    total_steps: int
    state: str = "queued"  # one of STATES
    steps: int = 0
    return_mean: float | None = None
    steps_per_sec: float | None = None
    attempts: int = 0  # tries of the chunk in flight on Ray (workers that died under it, plus one)
    error: str | None = None  # why a failed cell failed

    @classmethod
    def of(cls, key: str, run: Run, state: str, error: str | None = None) -> CellEvent:
        return cls(key, run.id, run.card.total_steps, state, run.card.steps_done, error=error)

    @property
    def resumed(self) -> bool:
        """A cell that starts training with steps done continues a checkpoint."""
        return self.steps > 0

    @property
    def eta_seconds(self) -> float | None:
        if not self.steps_per_sec or self.state != "training":
            return None
        return (self.total_steps - self.steps) / self.steps_per_sec


Progress = Callable[[list[CellEvent]], None]  # every unfinished cell's event, called as often as it changes


def training_units(cells: list[tuple[str, Run]], seeds_together: bool) -> list[list[tuple[str, Run]]]:
    """What an executor trains at once: each unfinished cell alone, or with the grid's `seeds_together` a
    cell's unfinished seeds (the same key but for the seed after the last "|"), in the cells' order. A group
    not yet marked as trained together is marked (its cards name each other), so a resume finds it."""
    unfinished = [(key, run) for key, run in cells if run.card.status != "completed"]
    if not seeds_together:
        return [[cell] for cell in unfinished]
    groups: dict[str, list[tuple[str, Run]]] = {}
    for key, run in unfinished:
        groups.setdefault(key.rsplit("|", 1)[0], []).append((key, run))
    for group in groups.values():
        if len(group) > 1 and not all(run.card.seeds_together for _, run in group):
            mark_together([run for _, run in group])
    return list(groups.values())


@runtime_checkable
class Executor(Protocol):
    """Trains a study's prepared cells."""

    def refuses(self, grid: Grid) -> str | None:
        """Why this executor cannot train the grid (checked before anything is prepared), or None."""
        ...

    def session(self) -> AbstractContextManager[object]:
        """Held around preparing and training: whatever must be there before any run folder is created (a
        Ray connection) is set up here, so that a missing extra or cluster is one line and no cell."""
        ...

    def run(self, study: Study, cells: list[tuple[str, Run]], on_progress: Progress | None) -> Iterator[CellEvent]:
        """Train the unfinished `cells`; yield an event when a cell starts and when it ends (`completed` or
        `failed`: one broken cell never stops the others). Ctrl-C or SIGTERM raise KeyboardInterrupt with
        every cell resumable from its last complete checkpoint."""
        ...


class Driver:
    """One session of a study: prepare it, train what is unfinished with an executor, refresh the report after
    each cell that ends and once at the end (also when cells failed: the others are reported), and collect
    the failures. `events()` yields a `done` event for each cell finished before, then the executor's
    events; afterwards `report` is the last report written and `failed` the cells that failed. An
    interruption is a MiktError saying which runs keep their checkpoints."""

    def __init__(self, study: Study, executor: Executor, command: str, *, retrain_missing: bool = False,
                 on_prepared: Callable[[list[tuple[str, Run]]], None] | None = None,
                 on_progress: Progress | None = None):
        self.study, self.executor, self.command, self.retrain_missing = study, executor, command, retrain_missing
        self.on_prepared, self.on_progress = on_prepared, on_progress
        self.training: dict[str, CellEvent] = {}  # in training now: what an interruption leaves resumable
        self.failed: list[CellEvent] = []
        self.report: Report | None = None

    def events(self) -> Iterator[CellEvent]:
        study = self.study
        if (why := self.executor.refuses(study.grid)) is not None:
            raise MiktError(f"grid '{study.grid.name}': {why}", hint="choose another executor, or change the grid")
        with study.driving(), self.executor.session():  # one driver per study folder, from its first cell on
            cells = study.prepare(self.command, self.retrain_missing)
            if self.on_prepared:
                self.on_prepared(cells)
            for key, run in cells:
                if run.card.status == "completed":
                    yield CellEvent.of(key, run, "done")
            try:
                for event in self.executor.run(study, cells, self._progress):
                    self._follow(event)
                    if event.state in ENDED:
                        self.report = study.report()  # after every cell: an interruption leaves a current report
                    yield event
            except KeyboardInterrupt:
                raise MiktError(f"interrupted; {self._kept()}",
                                hint="run the same command again to resume the study") from None
            self.report = study.report()

    def _follow(self, event: CellEvent) -> None:
        if event.state in ("training", "retrying"):
            self.training[event.run_id] = event
        else:
            self.training.pop(event.run_id, None)
        if event.state == "failed":
            self.failed.append(event)

    def _progress(self, events: list[CellEvent]) -> None:
        for event in events:
            if event.state != "failed":  # a failure is counted once, from the executor's event
                self._follow(event)
        if self.on_progress:
            self.on_progress(events)

    def _kept(self) -> str:
        if not self.training:
            return "every finished cell is kept"
        ids = sorted(self.training, key=run_number)
        return f"{ids[0]} keeps its last complete checkpoint" if len(ids) == 1 else (
            f"{', '.join(ids)} keep their last complete checkpoints")
