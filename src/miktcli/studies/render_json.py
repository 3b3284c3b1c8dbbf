"""summary.json and comparisons.json from a study's summary: the numbers of results.md, for scripts."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from miktcli.registry.files import write_text_atomic
from miktcli.studies.aggregates import PROFILE_MEASURE, AcrossPairs
from miktcli.studies.render_figures import PROFILE_FIGURE
from miktcli.studies.summary import MethodSummary, StudySummary, sample_std


def _json_number(value: float) -> float | None:
    return float(value) if math.isfinite(float(value)) else None


def _method_entry(m: MethodSummary, marks: dict[int, int]) -> dict[str, Any]:
    mean, std, auc = m.mean, m.std, m.mean_over_training
    return {
        "runs": [r.id for r in m.runs], "n": m.n,
        "final_eval_mean": float(np.mean(m.evals)), "final_eval_std": _json_number(sample_std(m.evals)),
        "final_train_mean": float(mean[-1]), "final_train_std": _json_number(std[-1]),
        "marks": {str(int(m.steps[i])): {"mean": float(mean[i]), "std": _json_number(std[i])}
                  for i in marks.values() if 0 <= i < len(mean)},
        "mean_over_training": float(np.mean(auc)), "mean_over_training_std": _json_number(sample_std(auc)),
        "steps_to_baseline_final": m.reach, "steps_to_three_quarters_of_baseline_final": m.reach_75,
    }


def across_pairs_json(a: AcrossPairs) -> dict[str, Any]:
    """The across-pairs section as plain data: its dataclasses' fields, measures and methods keyed by name. The
    profiles are a figure in results.md, and here too (their 101 thresholds a method would be most of the file)."""
    data = dataclasses.asdict(a)
    data["measures"] = {m["measure"]: {
        "methods": {x.pop("name"): x for x in m["methods"]},
        "probability_of_improvement": m["improvements"], "per_pair": m["per_pair"],
        "more_teachers_vs_fewer": [{**c, "intervals_overlap": matched.intervals_overlap}
                                   for c, matched in zip(m.pop("matched"), measure.matched, strict=True)]}
        for m, measure in zip(data["measures"], a.measures, strict=True)}
    data["profiles"] = ({"figure": PROFILE_FIGURE, "measure": PROFILE_MEASURE, "methods": [p.name for p in a.profiles]}
                        if a.profiles else None)
    return data


def summary_json(summary: StudySummary, sections: dict[str, Any]) -> dict[str, Any]:
    """Each pair's methods, then the sections' data by key (studies.sections), then the runs left out."""
    data: dict[str, Any] = {pair.name: {m.name: _method_entry(m, pair.marks) for m in pair.with_runs}
                            for pair in summary.pairs}
    data.update(sections)
    if summary.left_out:
        data["left_out"] = summary.left_out
    return data


def comparisons_json(summary: StudySummary) -> dict[str, list[dict[str, Any]]]:
    return {pair.name: pair.comparisons for pair in summary.pairs}


def write_json(summary: StudySummary, out_dir: Path, sections: dict[str, Any]) -> None:
    write_text_atomic(out_dir / "summary.json",
                      json.dumps(summary_json(summary, sections), indent=2, ensure_ascii=False))
    write_text_atomic(out_dir / "comparisons.json",
                      json.dumps(comparisons_json(summary), indent=2, ensure_ascii=False))
