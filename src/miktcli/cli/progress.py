"""Training progress on stderr: a Rich bar on a terminal, a plain line every few iterations otherwise."""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Iterator
from typing import Any

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from miktcli.cli.console import clean, err


def _fmt(value: float | None) -> str:
    return "—" if value is None or not math.isfinite(value) else f"{value:.1f}"


def track_training(metrics: Iterable[dict[str, Any]], total_steps: int, start_steps: int,
                   label: str) -> Iterator[dict[str, Any]]:
    if err.is_terminal:
        progress = Progress(
            TextColumn("{task.description}", style="bold", markup=False), BarColumn(), MofNCompleteColumn(),
            TextColumn("steps"),
            TextColumn("{task.fields[sps]} steps/s"), TextColumn("return {task.fields[ret]}"),
            TimeRemainingColumn(), console=err, transient=False,
        )
        with progress:
            task = progress.add_task(clean(label), total=total_steps, completed=start_steps, sps="—", ret="—")
            for m in metrics:
                progress.update(task, completed=m["steps"], sps=f"{m['steps_per_sec']:.0f}",
                                ret=_fmt(m["return_mean"]))
                yield m
        return
    last_print = 0.0
    for m in metrics:
        now = time.monotonic()
        if now - last_print > 30 or m["steps"] >= total_steps:
            err.print(f"{label}: {m['steps']}/{total_steps} steps, {m['steps_per_sec']:.0f} steps/s, "
                      f"return {_fmt(m['return_mean'])}")
            last_print = now
        yield m
