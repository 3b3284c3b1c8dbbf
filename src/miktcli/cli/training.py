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


def train_together_with_progress(runs, registry: Path, eval_episodes: int) -> list[dict]:
    """A cell's seeds trained together to their end, with progress on stderr (Ctrl-C goes through)."""
    from miktcli.workflows.session import run_to_end
    from miktcli.workflows.together import train_transfers_together

    lead = runs[0]
    sources = ", ".join(t.ref for t in lead.card.teachers) or "scratch"
    err.print(f"{together_label(runs)}: {lead.card.method} {sources} → {lead.card.env}, {lead.card.total_steps} "
              f"steps, seeds {', '.join(str(r.card.seed) for r in runs)} together → {lead.path.parent}")
    note_compile(lead)
    with training_progress(lead.card.total_steps, lead.card.steps_done, together_label(runs)) as show:
        return run_to_end(train_transfers_together(runs, registry, eval_episodes), show)


def together_label(runs) -> str:
    return f"{runs[0].id}–{runs[-1].id}" if len(runs) > 1 else runs[0].id


def train_together_run(runs, registry: Path, eval_episodes: int) -> list[dict]:
    """`mikt transfer --seeds`'s training (and a resume of such a group): Ctrl-C says how to resume."""
    try:
        return train_together_with_progress(runs, registry, eval_episodes)
    except KeyboardInterrupt:
        raise MiktError(f"interrupted; {together_label(runs)} keep their last complete checkpoints",
                        hint=f"continue with: mikt transfer --resume {runs[0].id}") from None


def train_cells(runs, registry: Path, eval_episodes: int) -> None:
    """A study's cells: one run alone, or a cell's seeds together."""
    if len(runs) == 1 and not runs[0].card.seeds_together:
        train_with_progress(runs[0], registry, eval_episodes)
    else:
        train_together_with_progress(runs, registry, eval_episodes)
