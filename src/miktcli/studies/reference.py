"""A reference result as data, and our runs measured the way it was measured.

A reference file (TOML) holds another implementation's published figures for some of a study's pairs, e.g.
CAT's training logs (the project's reference/cat-uai2022.toml): its estimator in words, the step windows it
averages over, and per run the teachers, the target and one return per window; optionally the hand-over at
its teacher drop (`hand_over`, with `hand_over_before`: the steps before the drop it averages) and each
branch's student weight at marks inside its coupling ramp (`ramp`, with `ramp_marks`). The report section
`reference` (studies.sections) sets a study's method beside it.

Our runs are measured with the reference's own estimator: the mean per-iteration return of the episodes that
finished in each rollout (`episode_return_iter`, CAT's `eprewmean`) over the iterations in a window, and the
student weight averaged over a branch's layers (as CAT logs `student_ps`).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from miktcli.errors import MiktError, describe_validation_error
from miktcli.limits import open_regular
from miktcli.registry.runs import Run

MAX_REFERENCE_BYTES = 1024 * 1024  # the committed reference is 4 kB


class AcrossDrop(BaseModel):
    """A run across its teacher drop as CAT's logs allow: the student weight p at the last update with the
    teachers, averaged over the layers of each branch, and the mean per-update return over a window up to the
    drop (`before`) and over everything after it (`after`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    drop: int
    p_pi: float
    p_vf: float
    before: float
    after: float


class Ramp(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    p_pi: list[float]
    p_vf: list[float]

    def branch(self, name: str) -> list[float]:
        return self.p_pi if name == "pi" else self.p_vf


class ReferenceRun(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    teachers: list[str] = Field(min_length=1)
    to: str
    returns: list[float]  # one per window
    hand_over: AcrossDrop | None = None
    ramp: Ramp | None = None


class Reference(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    estimator: str = ""
    windows: list[tuple[int, int]] = Field(min_length=1)
    runs: list[ReferenceRun]
    hand_over_before: int | None = Field(None, gt=0)  # steps: the window up to the drop that `before` averages
    ramp_marks: list[int] | None = None

    @model_validator(mode="after")
    def _consistent(self) -> Reference:
        if any(len(r.returns) != len(self.windows) for r in self.runs):
            raise ValueError(f"every run needs one return per window ({len(self.windows)})")
        if self.hand_over_before is None and any(r.hand_over for r in self.runs):
            raise ValueError("runs give a hand_over but the file has no hand_over_before (steps)")
        if any(r.ramp and any(len(v) != len(self.ramp_marks or []) for v in (r.ramp.p_pi, r.ramp.p_vf))
               for r in self.runs):
            raise ValueError("every run's ramp needs one student weight per ramp_marks entry")
        return self

    def on_targets(self, targets: dict[str, str]) -> Reference:
        """The same runs, each also under the names of ours that `targets` maps to its target (our target →
        the reference's): a reference run on another env name that stands for ours."""
        renamed = [r.model_copy(update={"to": ours}) for ours, theirs in targets.items()
                   for r in self.runs if r.to == theirs]
        return self.model_copy(update={"runs": [*self.runs, *renamed]})

    def run_for(self, teachers: str, to: str) -> ReferenceRun | None:
        """The reference's run of these teachers ("a+b", versions left out) and target, if it has one."""
        return next((r for r in self.runs if "+".join(r.teachers) == teachers and r.to == to), None)


def load_reference(path: Path) -> Reference:
    try:
        with open_regular(path, str(path)) as f:
            raw = f.read(MAX_REFERENCE_BYTES + 1)
        if len(raw) > MAX_REFERENCE_BYTES:
            raise MiktError(f"{path}: a reference file holds at most {MAX_REFERENCE_BYTES:,} bytes")
        return Reference.model_validate(tomllib.loads(raw.decode("utf-8")))
    except FileNotFoundError:
        raise MiktError(f"reference file {path} not found") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise MiktError(f"{path}: not a reference file: {err}") from None
    except ValidationError as err:
        raise MiktError(f"{path}: not a reference file: {describe_validation_error(err)}") from None


def window_mean(rows: list[dict], low: int, high: int) -> float:
    """The reference's estimator on one run's metrics rows: the mean of the per-iteration return of the
    episodes that finished in that iteration, over the iterations logged between `low` and `high` steps
    (iterations where none finished have no such return and are skipped, as CAT's logs have none). NaN where
    the window holds none."""
    values = [row["episode_return_iter"] for row in rows
              if low <= row["steps"] <= high and row.get("episode_return_iter") is not None]
    finite = [v for v in values if np.isfinite(v)]
    return float(np.mean(finite)) if finite else float("nan")


def last_coupled(rows: list[dict]) -> int | None:
    """The index of the last iteration that trained with the teachers (None: never, or never dropped them)."""
    coupled = [i for i, row in enumerate(rows) if row.get("teacher_active") == 1.0]
    return coupled[-1] if coupled and coupled[-1] < len(rows) - 1 else None


def branch_mean(row: dict, branch: str) -> float:
    """One branch's ("pi", "vf") student weight in a metrics row, averaged over its layers as CAT logs it."""
    weights = [v for k, v in row.items() if k.startswith(f"p_{branch}_") and v is not None]
    return float(np.mean(weights)) if weights else float("nan")


def branch_weight_at(rows: list[dict], step: int, branch: str) -> float:
    """A branch's layer-mean student weight at the last iteration at or before `step` (NaN before the first,
    or where that row logs none)."""
    before = [row for row in rows if row["steps"] <= step]
    return branch_mean(before[-1], branch) if before else float("nan")


def across_drop(rows: list[dict], before: int) -> AcrossDrop | None:
    """Our run measured like the reference's logs at the drop; None where it never dropped its teachers."""
    if (i := last_coupled(rows)) is None:
        return None
    drop = rows[i]["steps"]
    return AcrossDrop(drop=drop, p_pi=branch_mean(rows[i], "pi"), p_vf=branch_mean(rows[i], "vf"),
                      before=window_mean(rows, drop - before + 1, drop),
                      after=window_mean(rows, drop + 1, rows[-1]["steps"]))


@dataclass(frozen=True)
class HandOver:
    """One run at the teacher drop: the last iteration with the teachers, and what follows it."""

    step: int
    lowest_weight: float  # the smallest student weight p over the layers of policy and value
    at_drop: float  # the study's estimator (the last 100 episodes) at that iteration
    lowest_after: float
    at_end: float


def hand_over(run: Run) -> HandOver | None:
    """Where the run drops its teachers (None: it never trained with them, or never dropped them)."""
    rows = run.read_metrics()
    if (i := last_coupled(rows)) is None:
        return None
    last, after = rows[i], rows[i + 1:]
    weights = [v for k, v in last.items() if k.startswith(("p_pi_", "p_vf_")) and v is not None]
    returns = [row["return_mean"] for row in after if row.get("return_mean") is not None]
    if not weights or not returns or last.get("return_mean") is None:
        return None
    return HandOver(last["steps"], min(weights), last["return_mean"], min(returns), returns[-1])
