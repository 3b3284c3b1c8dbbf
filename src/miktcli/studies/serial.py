"""The embedded executor: a study's unfinished cells one after another, in this process, no Ray."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any, NamedTuple

from miktcli.registry.runs import Run, open_run
from miktcli.studies.study import Study
from miktcli.workflows.together import mark_together


class CellEvent(NamedTuple):
    key: str
    run: Run
    what: str  # done (finished before), start, resume, finished, failed
    error: str | None = None  # why a failed cell failed


def run_serially(study: Study, command: str, train: Callable[[list[Run]], Any],
                 retrain_missing: bool = False) -> Iterator[CellEvent]:
    """Every unfinished cell in turn; `train` trains and finishes runs: one, or with the grid's
    `seeds_together` a cell's unfinished seeds at once (one process, one batched update). A cell whose
    training raises is reported `failed` and the next trains, as on Ray: one broken cell never keeps the
    others from training, and a later run of the study retries it (a failed run is unfinished). Ctrl-C
    (KeyboardInterrupt) is no cell's failure: it stops the study."""
    together = study.grid.seeds_together
    waiting: list[tuple[str, Run]] = []
    for key, run in study.prepare(command, retrain_missing):
        if run.card.status == "completed":
            yield CellEvent(key, run, "done")
        elif together:
            waiting.append((key, run))
        else:
            yield from _train_cells(study, [(key, run)], train)
    groups: dict[str, list[tuple[str, Run]]] = {}
    for key, run in waiting:  # a cell's seeds: the same key but for the seed after the last "|"
        groups.setdefault(key.rsplit("|", 1)[0], []).append((key, run))
    for cells in groups.values():
        if len(cells) > 1 and not all(run.card.seeds_together for _, run in cells):
            mark_together([run for _, run in cells])
        yield from _train_cells(study, cells, train)


def _train_cells(study: Study, cells: list[tuple[str, Run]], train: Callable[[list[Run]], Any]
                 ) -> Iterator[CellEvent]:
    for key, run in cells:
        yield CellEvent(key, run, "resume" if run.card.steps_done else "start")
    try:
        train([run for _, run in cells])
    except Exception as err:  # noqa: BLE001 - whatever one cell's training raises is that cell's failure
        for key, run in cells:
            yield CellEvent(key, open_run(study.registry, run.id), "failed", f"{type(err).__name__}: {err}")
        return
    for key, run in cells:
        yield CellEvent(key, open_run(study.registry, run.id), "finished")
