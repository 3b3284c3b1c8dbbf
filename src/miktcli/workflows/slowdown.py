"""Flags a run whose update grows slower as it trains (issue 48: some runs' updates tripled mid-run).

The measure is the update's time over the rollout's in the same iteration, so that a machine that is busy
for a while (another process on the core) cancels out; its rolling median over 20 iterations is compared
with the lowest rolling median seen earlier in the same phase of the schedule (a phase may change the work
per update: the teachers join the loss in the ramp and leave at the drop)."""

from __future__ import annotations

import statistics
from collections import deque
from typing import Any

WINDOW = 20  # iterations in the rolling median
FACTOR = 2.0  # flagged when the rolling median reaches this multiple of the phase's lowest
# (the four slowed multi-cat runs reached 2.4-3.1x within their first phase, the other 14 at most 1.57x)


class SlowdownWatch:
    def __init__(self, history: list[tuple[str, int, float]] = ()):
        self.phase: str | None = None
        self.recent: deque[float] = deque(maxlen=WINDOW)
        self.lowest = float("inf")
        self.flagged: set[str] = set()
        for phase, step, ratio in history:  # a resumed run: the rows it already has
            self.add(phase, step, ratio)

    def add(self, phase: str, step: int, ratio: float) -> dict[str, Any] | None:
        """One iteration's ratio; a record the first time a phase's rolling median reaches FACTOR × its lowest."""
        if phase != self.phase:
            self.phase, self.lowest = phase, float("inf")
            self.recent.clear()
        if not ratio > 0:  # a row without timings (NaN, 0)
            return None
        self.recent.append(ratio)
        if len(self.recent) < WINDOW:
            return None
        median = statistics.median(self.recent)
        self.lowest = min(self.lowest, median)
        if median >= FACTOR * self.lowest and phase not in self.flagged:
            self.flagged.add(phase)
            return {"phase": phase, "step": step, "factor": round(median / self.lowest, 2),
                    "update_over_rollout": round(median, 3)}
        return None


def update_ratio(metrics: dict[str, Any]) -> float:
    rollout, update = metrics.get("time_rollout"), metrics.get("time_update")
    if not isinstance(rollout, int | float) or not isinstance(update, int | float) or rollout <= 0:
        return float("nan")
    return update / rollout
