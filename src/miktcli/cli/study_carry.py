"""`mikt study snapshot` and `mikt study restore`: a study's runs into its results folder (to commit or carry
to another machine) and back into a registry (studies.snapshots)."""

from __future__ import annotations

from pathlib import Path

import typer

from miktcli.cli.common import DEFAULT_REGISTRY, RegistryOption
from miktcli.cli.console import err, print_data


def _show(copied) -> None:
    for c in copied:
        err.print(f"{c.run_id}  {c.cell}: {c.what}")


def snapshot(
    results: Path = typer.Argument(..., help="The study's results folder (its --out)."),
    in_flight: bool = typer.Option(False, "--in-flight", help="Also keep the unfinished runs' checkpoints in "
                                   "RESULTS/in-flight/ (stop the study first: it resumes)."),
    registry: RegistryOption = DEFAULT_REGISTRY,
) -> None:
    """Copy the card and metrics of every finished run of a study into RESULTS/runs/, so its report
    regenerates from a fresh clone; with --in-flight, the unfinished runs' checkpoints too."""
    from miktcli.studies.snapshots import snapshot as take

    _show(take(results, registry, in_flight=in_flight))
    print_data(results)


def restore(
    results: Path = typer.Argument(..., help="The study's results folder (its --out)."),
    registry: RegistryOption = DEFAULT_REGISTRY,
) -> None:
    """Copy a study's snapshots back into a registry that lacks them, so the study skips its finished cells
    and resumes its in-flight ones; cells without a snapshot start afresh."""
    from miktcli.studies.snapshots import restore as put_back

    _show(put_back(results, registry))
    print_data(registry)
