"""A run's hand-over in numbers: the deterministic return with and without the teachers at the drop (what
the run recorded), and the per-update return (CAT's estimator: the mean over the episodes that finished in
one rollout) in windows on each side of it; and a pair's, over its seeds, beside the baseline from scratch on
the same windows. Used by study reports and the hand-over screening."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from miktcli.registry.runs import Run

WINDOW = 50_000  # env steps on each side of the drop (the 1.75-1.80M against 1.80-1.85M at 2M)


@dataclass(frozen=True)
class HandoverFigures:
    run: str
    handover: str
    at_step: int
    with_teachers: float  # deterministic return of the mixed policy just before the drop
    without_teachers: float  # of the teacher-free student right after the hand-over, same weights and episodes
    kept: float | None  # without / with (None when the mixed policy's return is not positive)
    before: float  # mean per-update return over the WINDOW steps before the drop
    after: float  # … over the WINDOW steps after it
    after_200k: float  # … over the 200k steps after it (the teacher-free phase of a 2M run)
    final: float | None  # mean of the last 100 training episodes at the end

    @property
    def change(self) -> float:
        return self.after - self.before


def window_mean(rows: list[dict[str, Any]], start: int, stop: int) -> float:
    """Mean per-update return over the iterations that end in (start, stop] (NaN rows skipped)."""
    values = [r["episode_return_iter"] for r in rows
              if start < r["steps"] <= stop and isinstance(r.get("episode_return_iter"), int | float)
              and math.isfinite(r["episode_return_iter"])]
    return float(np.mean(values)) if values else float("nan")


def handover_figures(run: Run, rows: list[dict[str, Any]] | None = None) -> HandoverFigures | None:
    """The figures of a run that recorded its hand-over (MIKT with the three-phase schedule), else None."""
    record = run.card.result.get("handover")
    if not isinstance(record, dict):
        return None
    rows = run.read_metrics() if rows is None else rows
    at = int(record["at_step"])
    options = run.card.config.options or {}
    return HandoverFigures(
        run=run.id, handover=str(options.get("handover", "drop")), at_step=at,
        with_teachers=float(record["with_teachers"]["return_mean"]),
        without_teachers=float(record["without_teachers"]["return_mean"]),
        kept=record.get("kept_fraction"),
        before=window_mean(rows, at - WINDOW, at), after=window_mean(rows, at, at + WINDOW),
        after_200k=window_mean(rows, at, at + 200_000),
        final=run.card.result.get("final_train_return"),
    )


@dataclass(frozen=True)
class PairHandover:
    """One method's hand-overs on one pair as seed means, beside the baseline from scratch on the same target over
    the same two windows: it drops nothing there, so its change is how much the window moves by itself (a
    learning curve late in a linearly decaying learning rate, and the noise of a few seeds)."""

    pair: str
    method: str
    runs: int
    at_step: int
    with_teachers: float
    without_teachers: float
    before: float
    after: float
    baseline: str
    baseline_runs: int
    baseline_before: float  # NaN without baseline runs
    baseline_after: float

    @property
    def kept(self) -> float | None:
        """The ratio of seed means, the issue's measure (None when the mixed policy's mean is not positive)."""
        return self.without_teachers / self.with_teachers if self.with_teachers > 0 else None

    @property
    def change(self) -> float:
        return self.after - self.before

    @property
    def baseline_change(self) -> float:
        return self.baseline_after - self.baseline_before


def pair_handover(pair: str, method: str, figures: list[HandoverFigures], baseline: str,
                  baseline_rows: list[list[dict[str, Any]]]) -> PairHandover:
    """`figures` (one per seed, at least one) as seed means; the baseline's runs (their metrics rows) read over
    the same windows, around the seeds' median drop step (one step in a grid: every run has the same budget)."""
    at = int(np.median([f.at_step for f in figures]))

    def mean(values: list[float]) -> float:  # over the runs with episodes in the window (NaN: none had)
        finite = [v for v in values if math.isfinite(v)]
        return float(np.mean(finite)) if finite else float("nan")

    return PairHandover(
        pair=pair, method=method, runs=len(figures), at_step=at,
        with_teachers=mean([f.with_teachers for f in figures]),
        without_teachers=mean([f.without_teachers for f in figures]),
        before=mean([f.before for f in figures]), after=mean([f.after for f in figures]),
        baseline=baseline, baseline_runs=len(baseline_rows),
        baseline_before=mean([window_mean(rows, at - WINDOW, at) for rows in baseline_rows]),
        baseline_after=mean([window_mean(rows, at, at + WINDOW) for rows in baseline_rows]),
    )


def pair_handover_json(h: PairHandover) -> dict[str, Any]:
    def number(x: float | None) -> float | None:
        return None if x is None or not math.isfinite(x) else float(x)

    return {**{k: number(v) if isinstance(v, float) else v for k, v in asdict(h).items()},
            "kept": number(h.kept), "change": number(h.change), "baseline_change": number(h.baseline_change)}
