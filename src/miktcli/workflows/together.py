"""Transfers of several seeds trained in one process (`mikt transfer --seeds 0-4`, a grid's
`seeds_together = true`): one run folder per seed as always, one batched update (miktcli.engine.together)."""

from __future__ import annotations

from collections.abc import Generator
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from miktcli.engine.together import SeedsTogether
from miktcli.errors import MiktError
from miktcli.registry.runs import Run, open_run
from miktcli.workflows.session import Event, Job, Phase
from miktcli.workflows.transfer import finish_transfer, start_transfer

MAX_SEEDS_TOGETHER = 64


def parse_seeds(text: str) -> list[int]:
    """`0-4`, `0,2,5` or both (`0-2,7`): distinct seeds in the order given."""
    seeds: list[int] = []
    try:
        for part in text.split(","):
            first, _, last = part.strip().partition("-")
            seeds += list(range(int(first), int(last) + 1)) if last else [int(first)]
    except ValueError:
        raise MiktError(f"--seeds '{text}': expected seeds like 0-4 or 0,2,5") from None
    if len(set(seeds)) != len(seeds):
        raise MiktError(f"--seeds '{text}' names a seed twice")
    if not 2 <= len(seeds) <= MAX_SEEDS_TOGETHER:
        raise MiktError(f"--seeds '{text}': {len(seeds)} seed(s); seeds together takes 2 to {MAX_SEEDS_TOGETHER}")
    return seeds


def start_transfers_together(registry: Path, seeds: list[int], **transfer: Any) -> list[Run]:
    """One run folder per seed (start_transfer's checks, each), marked as trained together."""
    runs = [start_transfer(registry, seed=seed, together=True, **transfer) for seed in seeds]
    mark_together(runs)
    return runs


def mark_together(runs: list[Run]) -> None:
    ids = [run.id for run in runs]
    for run in runs:
        run.save_card(seeds_together=ids)


def together_group(registry: Path, run: Run) -> list[Run]:
    """The unfinished runs of `run`'s group (itself included), to resume together; [run] for a run alone."""
    if not run.card.seeds_together:
        return [run]
    group = []
    for run_id in run.card.seeds_together:
        try:
            member = run if run_id == run.id else open_run(registry, run_id)
        except MiktError as err:
            raise MiktError(f"{run.id} trained together with {run_id}, which cannot be opened: {err}",
                            hint="resume from the registry that holds all of "
                                 f"{', '.join(run.card.seeds_together)}") from None
        if member.card.status != "completed":
            group.append(member)
    return group


def train_transfers_together(runs: list[Run], registry: Path, eval_episodes: int, max_iterations: int | None = None
                             ) -> Generator[Event, None, list[dict[str, Any]] | None]:
    """Train `runs` (one cell's seeds) to their end together, then evaluate and save each student. A group
    stopped between two seeds' checkpoints resumes with the seeds behind trained alone up to the others.
    With `max_iterations`, at most that many iterations together (a study on Ray trains a group in such
    chunks, as train_transfer_chunk does a run): if that does not reach the end, return None, every run
    resumable from its checkpoint."""
    with ExitStack() as stack:
        jobs = [stack.enter_context(Job(run, registry)) for run in runs]
        for job in jobs:
            yield from job.begin()
        furthest = max(job.trainer.iteration for job in jobs)
        for job in jobs:
            if job.trainer.iteration < furthest:
                for metrics in job.trainer.run():
                    yield from job.record(metrics)
                    if job.trainer.iteration >= furthest:
                        break
        together = SeedsTogether([job.trainer for job in jobs]).run() if len(jobs) > 1 else (
            [metrics] for metrics in jobs[0].trainer.run())
        done = 0
        for rows in together:
            for job, metrics in zip(jobs, rows, strict=True):
                yield from job.record(metrics)
            done += 1
            lead = jobs[0].trainer
            if max_iterations is not None and done >= max_iterations and lead.iteration < lead.num_iterations:
                return None
        results = []
        for job in jobs:
            yield Phase("evaluate", f"{job.run.id}, {eval_episodes} episodes")
            results.append(finish_transfer(job, eval_episodes))
        return results
