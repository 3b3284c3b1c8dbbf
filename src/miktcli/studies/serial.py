"""The embedded executor: a study's unfinished cells one after another, in this process, no Ray."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, nullcontext
from typing import Any

from miktcli.registry.runs import Run, open_run
from miktcli.studies.executor import CellEvent, Progress, training_units
from miktcli.studies.grid import Grid
from miktcli.studies.study import Study

Train = Callable[[list[Run]], Any]  # trains and finishes runs: one, or a cell's seeds together


class SerialExecutor:
    """Every unfinished cell in turn, trained by `train` (the CLI's shows a progress bar): one run, or with
    the grid's `seeds_together` a cell's unfinished seeds at once (one process, one batched update). A cell
    whose training raises is reported `failed` and the next trains, as on Ray: one broken cell never keeps
    the others from training, and a later run of the study retries it (a failed run is unfinished). Ctrl-C
    (KeyboardInterrupt) is no cell's failure: it stops the study."""

    def __init__(self, train: Train):
        self.train = train

    def refuses(self, grid: Grid) -> str | None:
        return None  # every grid trains here

    def session(self) -> AbstractContextManager[object]:
        return nullcontext()  # nothing to connect to

    def run(self, study: Study, cells: list[tuple[str, Run]], on_progress: Progress | None = None
            ) -> Iterator[CellEvent]:
        for unit in training_units(cells, study.grid.seeds_together):
            yield from self._train(study, unit)

    def _train(self, study: Study, cells: list[tuple[str, Run]]) -> Iterator[CellEvent]:
        for key, run in cells:
            yield CellEvent.of(key, run, "training")
        try:
            self.train([run for _, run in cells])
        except Exception as err:  # noqa: BLE001 - whatever one cell's training raises is that cell's failure
            for key, run in cells:
                yield CellEvent.of(key, open_run(study.registry, run.id), "failed", f"{type(err).__name__}: {err}")
            return
        for key, run in cells:
            yield CellEvent.of(key, open_run(study.registry, run.id), "completed")
