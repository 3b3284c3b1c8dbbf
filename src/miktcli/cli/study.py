"""`mikt study`: run a grid of transfers (pairs × methods × seeds), resumably, and report it; carry its runs."""

from __future__ import annotations

from pathlib import Path

import typer
from typer.core import TyperGroup

from miktcli.cli.common import DEFAULT_REGISTRY, RegistryOption, command_line, setup_torch
from miktcli.cli.console import err, print_data, print_error
from miktcli.cli.study_progress import StudyDisplay
from miktcli.errors import MiktError

HELP = """Run a study grid (pairs × methods × seeds), resumably, and write results.md with plots.

Examples:

  mikt study grid.toml                                   # results in ./studies/GRID-NAME

  mikt study grid.toml --workers 16                      # local Ray, 16 cells at once

  ray start --head && mikt study grid.toml --address auto   # an existing Ray cluster

  mikt study grid.toml --report-only

  mikt study --example tiny                              # a grid shipped with mikt (`mikt study examples`)

  mikt study snapshot studies/NAME   /   mikt study restore studies/NAME   # commit or carry its runs
"""


class StudyGroup(TyperGroup):
    """`mikt study GRID …` (or `mikt study --example NAME …`) is `mikt study run …`; `examples`, `snapshot` and
    `restore` are the other commands."""

    def parse_args(self, ctx, args):
        if args and args[0] not in self.commands and args[0] not in ctx.help_option_names:
            args = ["run", *args]
        return super().parse_args(ctx, args)


app = typer.Typer(cls=StudyGroup, help=HELP, no_args_is_help=True)


@app.command("run", help=HELP, no_args_is_help=True)
def study(
    grid_file: Path = typer.Argument(None, help="Grid TOML file.", show_default=False),
    example: str = typer.Option(None, "--example", metavar="NAME",
                                help="Run a grid shipped with mikt instead of a file (`mikt study examples`)."),
    out: Path = typer.Option(None, "--out", help="Results folder (default: ./studies/GRID-NAME)."),
    report_only: bool = typer.Option(False, "--report-only", help="Only aggregate what has finished."),
    workers: int = typer.Option(None, "--workers", min=1, help="Run cells in parallel on a local Ray instance "
                                "with this many CPUs (needs `pip install 'mikt\\[ray]'`)."),
    address: str = typer.Option(None, "--address", help="Run cells on an existing Ray cluster: auto or HOST:PORT."),
    chunk_iterations: int = typer.Option(20, "--chunk-iterations", min=1,
                                         help="On Ray: iterations per task before a cell's files come back."),
    retrain_missing: bool = typer.Option(
        False, "--retrain-missing", help="Train afresh the cells whose runs state.json names but the registry "
        "lacks (without it: an error, as the registry is usually the wrong one)."),
    registry: RegistryOption = DEFAULT_REGISTRY,
) -> None:
    from miktcli.studies.executor import Driver
    from miktcli.studies.grid import load_grid
    from miktcli.studies.study import Study

    grid_file, shown_as = _grid_source(grid_file, example)
    setup_torch()
    grid = load_grid(grid_file)
    st = Study(grid, out or Path("studies") / grid.name, registry)
    if report_only:
        _show_report(st.report_finished(shown_as))
        return
    on_ray = workers is not None or address is not None
    display = StudyDisplay(st, on_ray)
    driver = Driver(st, _executor(registry, workers, address, grid.eval_episodes, chunk_iterations), command_line(),
                    retrain_missing=retrain_missing, on_prepared=display.prepared,
                    on_progress=display.progress if on_ray else None)
    try:
        for event in driver.events():
            display.event(event)
    finally:
        display.close()
    _show_report(driver.report)
    for event in driver.failed:
        print_error(f"{event.key}: {event.run_id} failed: {event.error}")
    if driver.failed:
        raise MiktError(f"{len(driver.failed)} cell(s) failed; the others are reported",
                        hint="see `mikt inspect RUN` for each failed run; running the study again retries them")


def _grid_source(grid_file: Path | None, example: str | None) -> tuple[Path, str]:
    """The grid file to read, and how to name it again in a hint (the way the user gave it)."""
    if (grid_file is None) == (example is None):
        raise typer.BadParameter("give a grid file or --example NAME (one of them)", param_hint="'GRID_FILE'")
    if example is None:
        return grid_file, str(grid_file)
    from miktcli.examples import example as find_example

    return find_example(example).path, f"--example {example}"


def _executor(registry: Path, workers: int | None, address: str | None, eval_episodes: int, chunk_iterations: int):
    if workers is None and address is None:  # embedded: serial, in this process, no Ray
        from miktcli.cli.training import train_cells
        from miktcli.studies.serial import SerialExecutor

        return SerialExecutor(lambda runs: train_cells(runs, registry, eval_episodes))
    from miktcli.studies.ray_executor import RayExecutor

    return RayExecutor(workers, address, eval_episodes, chunk_iterations)


def _show_report(report) -> None:
    for problem in report.left_out:
        err.print(f"warning: left out of the report: {problem}")
    err.print(f"wrote {report.path}")
    print_data(report.path)
