"""Training a prepared run to its end with progress on stderr: shared by `mikt transfer` and `mikt study`."""

from __future__ import annotations

from pathlib import Path

from miktcli.cli.common import note_compile
from miktcli.cli.console import err
from miktcli.cli.progress import training_progress
from miktcli.errors import MiktError


def train_with_progress(run, registry: Path, eval_episodes: int) -> dict:
    """Train a transfer run to its end with progress on stderr, then evaluate and save its student. Ctrl-C
    (KeyboardInterrupt) goes through: the caller knows which command resumes it."""
    from miktcli.workflows.session import run_to_end
    from miktcli.workflows.transfer import train_transfer

    sources = ", ".join(t.ref for t in run.card.teachers) or "scratch"
    err.print(f"{run.id}: {run.card.method} {sources} → {run.card.env}, {run.card.total_steps} steps, "
              f"seed {run.card.seed} → {run.path}")
    note_compile(run)
    with training_progress(run.card.total_steps, run.card.steps_done, run.id) as show:
        return run_to_end(train_transfer(run, registry, eval_episodes), show)


def train_transfer_run(run, registry: Path, eval_episodes: int) -> dict:
    """`mikt transfer`'s training: as train_with_progress, and Ctrl-C says how to resume the run."""
    try:
        return train_with_progress(run, registry, eval_episodes)
    except KeyboardInterrupt:
        raise MiktError(f"interrupted; {run.id} keeps its last complete checkpoint",
                        hint=f"continue with: mikt transfer --resume {run.id}") from None
