"""Training and evaluation progress on stderr: a Rich bar on a terminal, a plain line now and then otherwise.

Workflows yield events (an iteration's metrics, or a Phase; an evaluation's EpisodeDone); `training_progress`
and `episode_progress` give the callbacks that show them."""

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


EPISODE_LINE_EVERY_S = 10  # off a terminal: the first episode, then a line at most this often, and the last


@contextlib.contextmanager
def episode_progress(total: int, label: str, recording: bool) -> Iterator[Callable[[Any], None]]:
    """A callback for an evaluation's EpisodeDone events (engine.episodes): a bar, or plain lines."""
    def detail(event: Any) -> str:
        frames = f", {event.frames:,} frames recorded" if recording else ""
        return f"return {event.ret:.1f}, length {event.length:,}{frames}"

    if err.is_terminal:
        progress = Progress(
            TextColumn("{task.description}", style="bold", markup=False), BarColumn(), MofNCompleteColumn(),
            TextColumn("episodes"), TextColumn("{task.fields[last]}", markup=False), TimeRemainingColumn(),
            console=err, transient=False,
        )
        with progress:
            task = progress.add_task(clean(label), total=total, last="")

            def show(event: Any) -> None:
                progress.update(task, completed=event.number, last=f"last: {detail(event)}")

            yield show
        return
    last_print = [-math.inf]

    def show_plain(event: Any) -> None:
        now = time.monotonic()
        if now - last_print[0] >= EPISODE_LINE_EVERY_S or event.number == event.episodes:
            err.print(f"{label}: episode {event.number}/{event.episodes}, {detail(event)}")
            last_print[0] = now

    yield show_plain
