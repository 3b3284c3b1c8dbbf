"""Training a prepared run to its end with progress on stderr: shared by `mikt transfer` and `mikt study`."""

from __future__ import annotations

from pathlib import Path

from miktcli.cli.console import err
from miktcli.cli.progress import training_progress
from miktcli.errors import MiktError


def train_transfer_run(run, registry: Path, eval_episodes: int) -> dict:
    """Train a transfer run to its end with progress on stderr, then evaluate and save its student."""
    from miktcli.workflows.session import run_to_end
    from miktcli.workflows.transfer import train_transfer

    sources = ", ".join(t.ref for t in run.card.teachers) or "scratch"
    err.print(f"{run.id}: {run.card.method} {sources} → {run.card.env}, {run.card.total_steps} steps, "
              f"seed {run.card.seed} → {run.path}")
    try:
        with training_progress(run.card.total_steps, run.card.steps_done, run.id) as show:
            return run_to_end(train_transfer(run, registry, eval_episodes), show)
    except KeyboardInterrupt:
        raise MiktError(f"interrupted; {run.id} keeps its last complete checkpoint",
                        hint=f"continue with: mikt transfer --resume {run.id}") from None
