"""`mikt study`: run a grid of transfers (pairs × methods × seeds), resumably, and report it."""

from __future__ import annotations

import time
from pathlib import Path

import typer
from rich.live import Live
from rich.table import Table

from miktcli.cli.common import DEFAULT_REGISTRY, RegistryOption, command_line, setup_torch
from miktcli.cli.console import err, print_data, print_error
from miktcli.errors import MiktError

HELP = """Run a study grid (pairs × methods × seeds), resumably, and write results.md with plots.

Examples:

  mikt study benchmarks/grids/four-to-eight.toml

  mikt study benchmarks/grids/paper-2m.toml --workers 16          # local Ray, 16 cells at once

  ray start --head && mikt study grid.toml --address auto         # an existing Ray cluster

  mikt study benchmarks/grids/four-to-eight.toml --report-only
"""


def _duration(seconds: float | None) -> str:
    if seconds is None:
        return "—"
    minutes, secs = divmod(int(seconds), 60)
    return f"{minutes // 60}:{minutes % 60:02d}:{secs:02d}"


def _overview(cells, finished_before: int) -> str:
    """The whole study in one line: cells done, what is left, and when it ends at the current pace."""
    done = finished_before + sum(c.state == "completed" for c in cells)
    training = sum(c.state in ("training", "retrying") for c in cells)
    failed = sum(c.state == "failed" for c in cells)
    left = sum(c.total_steps - c.steps for c in cells if c.state not in ("completed", "failed"))
    # The running cells' summed pace: cells of other methods run at other speeds, so this is an estimate.
    rate = sum(c.steps_per_sec or 0.0 for c in cells if c.state == "training")
    line = f"{done}/{finished_before + len(cells)} cells completed, {training} training"
    line += f", {failed} failed" if failed else ""
    line += f"; {left:,} steps to go"
    return line + (f", about {_duration(left / rate)} at the current {rate:,.0f} steps/s" if rate and left else "")


def _progress_table(cells, finished_before: int) -> Table:
    table = Table("cell (teachers > target | method | seed)", "run", "state", "steps", "return", "steps/s", "ETA",
                  title="mikt study on Ray", title_justify="left", caption=_overview(cells, finished_before),
                  caption_justify="left")
    for c in cells:
        ret = "—" if c.return_mean is None else f"{c.return_mean:.1f}"
        sps = "—" if c.steps_per_sec is None else f"{c.steps_per_sec:.0f}"
        table.add_row(c.key, c.run_id, c.state, f"{c.steps:,}/{c.total_steps:,}", ret, sps, _duration(c.eta_seconds))
    return table


class _PlainProgress:
    """One line per cell whose steps moved, then the study's overview, at most every 30 s, when stderr is not
    a terminal."""

    def __init__(self, finished_before: int):
        self.finished_before = finished_before
        self.shown: dict[str, tuple[int, str]] = {}
        self.last = 0.0

    def __call__(self, cells) -> None:
        if time.monotonic() - self.last < 30:
            return
        self.last = time.monotonic()
        moved = False
        for c in cells:
            if self.shown.get(c.run_id) != (c.steps, c.state):
                self.shown[c.run_id] = (c.steps, c.state)
                moved = True
                err.print(f"{c.key}: {c.run_id} {c.state} {c.steps:,}/{c.total_steps:,} steps"
                          + ("" if c.return_mean is None else f", return {c.return_mean:.1f}"))
        if moved:
            err.print(f"study: {_overview(cells, self.finished_before)}")


def study(
    grid_file: Path = typer.Argument(..., help="Grid TOML file."),
    out: Path = typer.Option(None, "--out", help="Results folder (default: benchmarks/results/GRID-NAME)."),
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
    from miktcli.studies.grid import load_grid
    from miktcli.studies.study import Study

    setup_torch()
    grid = load_grid(grid_file)
    st = Study(grid, out or Path("benchmarks/results") / grid.name, registry)
    if report_only:
        st.check_envs()  # the other branches check it before any cell is created
        if not st.cells:  # an empty report would pass for a study without results
            why = f"{st.state_path.name} names no cell" if st.state_path.is_file() else f"no {st.state_path.name}"
            raise MiktError(f"{st.out_dir} holds no study yet ({why}): nothing to report",
                            hint=f"is --out right? Start the study with: mikt study {grid_file} --out {st.out_dir}")
        _report(st)
        return
    with st.driving():  # one driver per study folder, from its first prepared cell to its report
        if workers is None and address is None:  # embedded: serial, in this process, no Ray
            failed = _run_serially(st, registry, grid.eval_episodes, retrain_missing)
        else:
            if grid.seeds_together:
                raise MiktError(f"{grid_file}: seeds_together trains a cell's seeds in this process; the Ray "
                                "executor trains one seed a task", hint="run the study without --workers "
                                "and --address, or set seeds_together = false")
            failed = _run_on_ray(st, registry, workers, address, grid.eval_episodes, chunk_iterations,
                                 retrain_missing)
        _report(st)  # also when cells failed: the others are reported, the failed ones named
    for key, run_id, error in failed:
        print_error(f"{key}: {run_id} failed: {error}")
    if failed:
        raise MiktError(f"{len(failed)} cell(s) failed; the others are reported",
                        hint="see `mikt inspect RUN` for each failed run; running the study again retries them")


def _report(st) -> None:
    report = st.report()
    for problem in report.left_out:
        err.print(f"warning: left out of the report: {problem}")
    err.print(f"wrote {report.path}")
    print_data(report.path)


def _announce_pins(st) -> None:
    """The versions this run of the study pinned for references that name none (studies.pins)."""
    for ref, pin in st.new_pins:
        if "@v" not in ref:
            name = ref.split("@")[0]
            err.print(f"study: `{ref}` pinned to {pin.ref} ({st.pins_path.name}); a later version of {name} "
                      "does not change this study")


def _run_serially(st, registry: Path, eval_episodes: int, retrain_missing: bool) -> list[tuple[str, str, str]]:
    """Every unfinished cell in this process, one after another; (cell, run id, error) of each that failed."""
    from miktcli.cli.training import train_cells
    from miktcli.studies.serial import run_serially

    total = len(st.distinct_cells())
    done, failed, training, announced = 0, [], None, False
    try:
        for event in run_serially(st, command_line(), lambda rs: train_cells(rs, registry, eval_episodes),
                                  retrain_missing):
            training = None
            if not announced:  # the first event comes right after the study was prepared
                _announce_pins(st)
                announced = True
            if event.what in ("done", "finished"):
                done += 1
                err.print(f"[{done}/{total}] {event.key}: {event.run.id} completed")
                st.report()  # refreshed after every cell, so an interruption leaves a current report
            elif event.what == "failed":
                failed.append((event.key, event.run.id, event.error))
                err.print(f"{event.key}: {event.run.id} failed: {event.error}; going on with the next cell")
                st.report()
            else:
                training = event.run.id
                err.print(f"{event.key}: {event.what} {event.run.id}")
    except KeyboardInterrupt:
        kept = f"{training} keeps its last complete checkpoint" if training else "every finished cell is kept"
        raise MiktError(f"interrupted; {kept}", hint="run the same command again to resume the study") from None
    return failed


def _run_on_ray(st, registry: Path, workers: int | None, address: str | None, eval_episodes: int,
                chunk_iterations: int, retrain_missing: bool) -> list[tuple[str, str, str]]:
    """The unfinished cells on Ray; (cell, run id, error) of each that failed."""
    from miktcli.studies.ray_executor import ray_session

    # connected before any run folder is created: a missing extra or a cluster that is not there is one line
    with ray_session(workers, address):
        return _train_on_ray(st, registry, workers, address, eval_episodes, chunk_iterations, retrain_missing)


def _train_on_ray(st, registry: Path, workers: int | None, address: str | None, eval_episodes: int,
                  chunk_iterations: int, retrain_missing: bool) -> list[tuple[str, str, str]]:
    from miktcli.studies.ray_executor import run_cells_on_ray

    cells = st.prepare(command_line(), retrain_missing)
    _announce_pins(st)
    finished_before = sum(run.card.status == "completed" for _, run in cells)  # the progress shows the rest
    failed = []
    live = Live(console=err, refresh_per_second=2, transient=False) if err.is_terminal else None
    show = (lambda cells: live.update(_progress_table(cells, finished_before))) if live else _PlainProgress(
        finished_before)
    try:
        if live:
            live.start()
        for progress in run_cells_on_ray(registry, cells, workers=workers, address=address,
                                         eval_episodes=eval_episodes, chunk_iterations=chunk_iterations,
                                         on_progress=show):
            if progress.state == "failed":
                failed.append(progress)
            else:
                st.report()
            if not live:
                err.print(f"{progress.key}: {progress.run_id} {progress.state}")
    except KeyboardInterrupt:
        raise MiktError("interrupted; every cell keeps its last handed-back checkpoint",
                        hint="run the same command again to resume the study") from None
    finally:
        if live:
            live.stop()
    return [(p.key, p.run_id, p.error or "no error recorded") for p in failed]
