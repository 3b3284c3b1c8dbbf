"""Training progress on stderr: a Rich bar on a terminal, a plain line every few iterations otherwise.

Workflows yield events (an iteration's metrics, or a Phase); `training_progress` gives the callback that
shows them."""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Iterator
from typing import Any

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from miktcli.cli.console import clean, err


def _fmt(value: float | None) -> str:
    return "—" if value is None or not math.isfinite(value) else f"{value:.1f}"


@contextlib.contextmanager
def training_progress(total_steps: int, start_steps: int, label: str) -> Iterator[Callable[[Any], None]]:
    """A callback for workflow events: iterations move the bar (or print a line every 30 s), phases print."""
    from miktcli.workflows.session import Phase

    if err.is_terminal:
        progress = Progress(
            TextColumn("{task.description}", style="bold", markup=False), BarColumn(), MofNCompleteColumn(),
            TextColumn("steps"), TextColumn("{task.fields[sps]} steps/s"), TextColumn("return {task.fields[ret]}"),
            TimeRemainingColumn(), console=err, transient=False,
        )
        with progress:
            task = progress.add_task(clean(label), total=total_steps, completed=start_steps, sps="—", ret="—")

            def show(event: Any) -> None:
                if isinstance(event, Phase):
                    progress.console.print(f"{label}: {event.name} {event.detail}".rstrip())
                else:
                    progress.update(task, completed=event["steps"], sps=f"{event['steps_per_sec']:.0f}",
                                    ret=_fmt(event["return_mean"]))

            yield show
        return
    last_print = [0.0]

    def show_plain(event: Any) -> None:
        if isinstance(event, Phase):
            err.print(f"{label}: {event.name} {event.detail}".rstrip())
            return
        now = time.monotonic()
        if now - last_print[0] > 30 or event["steps"] >= total_steps:
            err.print(f"{label}: {event['steps']}/{total_steps} steps, {event['steps_per_sec']:.0f} steps/s, "
                      f"return {_fmt(event['return_mean'])}")
            last_print[0] = now

    yield show_plain
