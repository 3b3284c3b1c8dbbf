"""What `mikt study` shows while it trains: the Ray table (a live one on a terminal, lines otherwise), the
serial executor's line per cell, and the study's overview."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from rich.live import Live
from rich.table import Table

from miktcli.cli.console import err

if TYPE_CHECKING:  # the study machinery (reports, scipy) is imported by `mikt study` alone, not by every command
    from miktcli.studies.executor import CellEvent


def duration(seconds: float | None) -> str:
    if seconds is None:
        return "—"
    minutes, secs = divmod(int(seconds), 60)
    return f"{minutes // 60}:{minutes % 60:02d}:{secs:02d}"


def overview(cells: list[CellEvent], finished_before: int) -> str:
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
    return line + (f", about {duration(left / rate)} at the current {rate:,.0f} steps/s" if rate and left else "")


def progress_table(cells: list[CellEvent], finished_before: int) -> Table:
    table = Table("cell (teachers > target | method | seed)", "run", "state", "steps", "return", "steps/s", "ETA",
                  title="mikt study on Ray", title_justify="left", caption=overview(cells, finished_before),
                  caption_justify="left")
    for c in cells:
        ret = "—" if c.return_mean is None else f"{c.return_mean:.1f}"
        sps = "—" if c.steps_per_sec is None else f"{c.steps_per_sec:.0f}"
        table.add_row(c.key, c.run_id, c.state, f"{c.steps:,}/{c.total_steps:,}", ret, sps, duration(c.eta_seconds))
    return table


class PlainProgress:
    """One line per cell whose steps moved, then the study's overview, at most every 30 s, when stderr is not
    a terminal."""

    def __init__(self, finished_before: int):
        self.finished_before = finished_before
        self.shown: dict[str, tuple[int, str]] = {}
        self.last = 0.0

    def __call__(self, cells: list[CellEvent]) -> None:
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
            err.print(f"study: {overview(cells, self.finished_before)}")


def cell_line(event: CellEvent, done: int, total: int) -> str | None:
    """The serial executor's line for one event: a cell that starts or resumes, completes or fails."""
    if event.state == "training":
        return f"{event.key}: {'resume' if event.resumed else 'start'} {event.run_id}"
    if event.state in ("done", "completed"):  # done: completed before this session
        return f"[{done}/{total}] {event.key}: {event.run_id} completed"
    if event.state == "failed":
        return f"{event.key}: {event.run_id} failed: {event.error}; going on with the next cell"
    return None


def pin_lines(study) -> list[str]:
    """The versions this session pinned for references that name none (studies.pins)."""
    pins = study.teacher_pins
    return [f"study: `{ref}` pinned to {pin.ref} ({pins.path.name}); a later version of "
            f"{ref.split('@')[0]} does not change this study" for ref, pin in pins.new if "@v" not in ref]


class StudyDisplay:
    """All `mikt study` shows while it runs, fed by the driver: the pins once the cells are prepared, then on Ray
    the progress table (live on a terminal, else `PlainProgress`) and a line per finished task, or serially a
    line per cell (`cell_line`)."""

    def __init__(self, study, on_ray: bool):
        self.study, self.on_ray = study, on_ray
        self.live = Live(console=err, refresh_per_second=2) if on_ray and err.is_terminal else None
        self.plain = PlainProgress(0)
        self.done, self.total = 0, len(study.distinct_cells())

    def prepared(self, cells) -> None:
        for line in pin_lines(self.study):
            err.print(line)
        self.plain.finished_before = sum(run.card.status == "completed" for _, run in cells)
        if self.live:
            self.live.start()

    def progress(self, cells: list[CellEvent]) -> None:
        if self.live:
            self.live.update(progress_table(cells, self.plain.finished_before))
        else:
            self.plain(cells)

    def event(self, event: CellEvent) -> None:
        self.done += event.state in ("done", "completed")
        line = (f"{event.key}: {event.run_id} {event.state}" if self.on_ray
                else cell_line(event, self.done, self.total))
        if line and not self.live:
            err.print(line)

    def close(self) -> None:
        if self.live:
            self.live.stop()
