"""`mikt study`: run a grid of transfers (pairs × methods × seeds), resumably, and report it."""

from __future__ import annotations

from pathlib import Path

import typer

from miktcli.cli.common import DEFAULT_REGISTRY, RegistryOption, command_line, setup_torch
from miktcli.cli.console import err, print_data

HELP = """Run a study grid (pairs × methods × seeds), resumably, and write results.md with plots.

Examples:

  mikt study benchmarks/grids/four-to-eight.toml

  mikt study benchmarks/grids/four-to-eight.toml --report-only
"""


def study(
    grid_file: Path = typer.Argument(..., help="Grid TOML file."),
    out: Path = typer.Option(None, "--out", help="Results folder (default: benchmarks/results/GRID-NAME)."),
    report_only: bool = typer.Option(False, "--report-only", help="Only aggregate what has finished."),
    registry: RegistryOption = DEFAULT_REGISTRY,
) -> None:
    from miktcli.cli.transfer import train_transfer_run
    from miktcli.workflows.grid import load_grid
    from miktcli.workflows.study import Study

    setup_torch()
    reg = registry
    grid = load_grid(grid_file)
    st = Study(grid, out or Path("benchmarks/results") / grid.name, reg)
    if not report_only:
        total = len(st.distinct_cells())
        done = 0
        for key, run, what in st.execute(command_line(), lambda r: train_transfer_run(r, reg, grid.eval_episodes)):
            if what in ("done", "finished"):
                done += 1
                err.print(f"[{done}/{total}] {key}: {run.id} completed")
                st.report()  # refreshed after every cell, so an interruption leaves a current report
            else:
                err.print(f"{key}: {what} {run.id}")
    path = st.report()
    err.print(f"wrote {path}")
    print_data(path)
