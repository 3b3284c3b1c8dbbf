"""The embedded executor: a study's unfinished cells one after another, in this process, no Ray."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any, NamedTuple

from miktcli.registry.runs import Run, open_run
from miktcli.studies.study import Study


class CellEvent(NamedTuple):
    key: str
    run: Run
    what: str  # done (finished before), start, resume, finished, failed
    error: str | None = None  # why a failed cell failed


def run_serially(study: Study, command: str, train: Callable[[Run], Any],
                 retrain_missing: bool = False) -> Iterator[CellEvent]:
    """Every unfinished cell in turn; `train` trains and finishes a run. A cell whose training raises is
    reported `failed` and the next cell trains, as on Ray: one broken cell never keeps the others from
    training, and a later run of the study retries it (a failed run is unfinished). Ctrl-C (KeyboardInterrupt)
    is no cell's failure: it stops the study."""
    for key, run in study.prepare(command, retrain_missing):
        if run.card.status == "completed":
            yield CellEvent(key, run, "done")
            continue
        yield CellEvent(key, run, "resume" if run.card.steps_done else "start")
        try:
            train(run)
        except Exception as err:  # noqa: BLE001 - whatever one cell's training raises is that cell's failure
            yield CellEvent(key, open_run(study.registry, run.id), "failed", f"{type(err).__name__}: {err}")
            continue
        yield CellEvent(key, open_run(study.registry, run.id), "finished")
