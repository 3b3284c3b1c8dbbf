"""Curves that span several studies' committed snapshots, put side by side on one set of seeds: what the
teacher-similarity and controls/ablations reports share.

A *group* is one curve: a label, the grid and snapshot folder it comes from, its pair and its method. Runs are
read from `STUDY/runs/RUN/` (written by `mikt study snapshot`), so the reports work from a fresh clone without
a registry.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from miktcli.errors import MiktError
from miktcli.registry.cards import RunCard
from miktcli.registry.runs import Run
from miktcli.studies.grid import Grid, MethodSpec, PairSpec
from miktcli.studies.summary import RunOf, completed_curves, mean_pm_std, sample_std


def snapshot_runs(results: Path) -> RunOf:
    """A cell key → its run, read from the study's snapshot folder (None when not finished and copied)."""
    state = json.loads((results / "state.json").read_text()) if (results / "state.json").exists() else {}

    def run_of(key: str) -> Run | None:
        folder = results / "runs" / state.get(key, "-")
        if not (folder / "run.json").is_file():
            return None
        return Run(folder, RunCard.model_validate_json((folder / "run.json").read_text()))

    return run_of


def method_named(grid: Grid, name: str) -> MethodSpec:
    for method in grid.methods:
        if method.name == name:
            return method
    raise MiktError(f"grid '{grid.name}' has no method '{name}'",
                    hint=f"its methods: {', '.join(m.name for m in grid.methods)}")


@dataclass
class Group:
    label: str
    grid: Grid
    run_of: RunOf
    pair: PairSpec
    method: MethodSpec


@dataclass
class Curves:
    """What a report prints and draws for its groups."""

    rows: list[str] = field(default_factory=list)  # markdown table rows, one per group (header excluded)
    series: dict[str, list[tuple[float, float]]] = field(default_factory=dict)
    bands: dict[str, list[tuple[float, float, float]]] = field(default_factory=dict)
    weights: dict[str, list[tuple[float, float]]] = field(default_factory=dict)  # mean p_pi_0 per group
    per_seed: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)  # for compare_methods
    left_out: list[str] = field(default_factory=list)

    @property
    def counts(self) -> dict[str, int]:
        """Finished seeds per group with a curve (each has one per-seed value per run)."""
        return {label: len(measures["final return"]) for label, measures in self.per_seed.items()}

    @property
    def weight_counts(self) -> dict[str, int]:
        """The same counts keyed by each group's student-weight curve (a group without mixing draws none)."""
        return {weight_label(label): n for label, n in self.counts.items() if weight_label(label) in self.weights}


def weight_label(group: str) -> str:
    """The legend name of a group's mean student-weight curve (the policy's weight, p_pi_0)."""
    return f"{group} (π)"


def columns(marks: list[int]) -> list[str]:
    return ["curve", "n", *(f"{m:,}" for m in marks), "mean over training", "final eval (no teacher)",
            "final p (π / V)"]


def table_head(marks: list[int]) -> list[str]:
    """The markdown header and rule of the table that `curves_of` fills."""
    names = columns(marks)
    return ["| " + " | ".join(names) + " |", "|" + "---|" * len(names)]


def curves_of(groups: list[Group], seeds: list[int], marks: list[int]) -> Curves:
    """Each group's completed runs on `seeds` only (so every curve averages the same seeds): mean ± sample std
    at each mark (the last iteration at or before it), over training, and of the teacher-free eval."""
    out = Curves()
    width = len(columns(marks)) - 2
    for g in groups:
        runs, steps, curves = completed_curves(g.grid.model_copy(update={"seeds": seeds}), g.run_of, g.pair,
                                               g.method, out.left_out)
        if not runs:
            out.rows.append(f"| {g.label} | 0 | " + " | ".join("—" for _ in range(width)) + " |")
            continue
        mean, std = np.nanmean(curves, 0), np.nan_to_num(sample_std(curves, axis=0))
        at = [int(np.searchsorted(steps, m, side="right")) - 1 for m in marks]
        cells = ["—" if i < 0 else mean_pm_std(curves[:, i]) for i in at]
        evals = np.array([r.card.result["eval_without_teacher"]["return_mean"] for r in runs], dtype=float)
        auc = np.nanmean(curves, axis=1)
        mixing = [r.card.result.get("final_mixing_learned") or {} for r in runs]
        p = "—"
        if all(m.get("p_pi_0") is not None for m in mixing):
            p = f"{np.mean([m['p_pi_0'] for m in mixing]):.2f} / {np.mean([m['p_vf_0'] for m in mixing]):.2f}"
            # averaged at the steps every run logged (a damaged metrics line drops a step, never shifts one)
            by_step = [{row["steps"]: row.get("p_pi_0") for row in r.read_metrics()} for r in runs]
            common = sorted(set.intersection(*(set(b) for b in by_step)))
            out.weights[weight_label(g.label)] = [(step, float(np.mean([b[step] for b in by_step])))
                                                  for step in common if all(b[step] is not None for b in by_step)]
        out.rows.append(f"| {g.label} | {len(runs)} | " + " | ".join(cells)
                        + f" | {mean_pm_std(auc)} | {mean_pm_std(evals)} | {p} |")
        out.series[g.label] = list(zip(steps.tolist(), mean.tolist(), strict=True))
        out.bands[g.label] = list(zip(steps.tolist(), (mean - std).tolist(), (mean + std).tolist(), strict=True))
        out.per_seed[g.label] = {"final return": curves[:, -1], "mean over training": auc,
                                 "final eval (no teacher)": evals}
    return out
