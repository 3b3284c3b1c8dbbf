"""The embedded executor: a study's unfinished cells one after another, in this process, no Ray."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

from miktcli.registry.runs import Run, open_run
from miktcli.studies.study import Study


def run_serially(study: Study, command: str, train: Callable[[Run], Any],
                 retrain_missing: bool = False) -> Iterator[tuple[str, Run, str]]:
    """Every unfinished cell in turn. Yields (cell, run, what happened: done, start or resume, finished);
    `train` trains and finishes a run."""
    for key, run in study.prepare(command, retrain_missing):
        if run.card.status == "completed":
            yield key, run, "done"
            continue
        yield key, run, "resume" if run.card.steps_done else "start"
        train(run)
        yield key, open_run(study.registry, run.id), "finished"
