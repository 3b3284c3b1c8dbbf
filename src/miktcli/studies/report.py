"""The study report: one summary (studies.summary) with its numbers across pairs (studies.aggregates), then
its renderers: results.md, summary.json and comparisons.json, the figures and the TensorBoard tree."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import NamedTuple

from miktcli.errors import MiktError
from miktcli.registry.files import write_text_atomic
from miktcli.studies.aggregates import AcrossPairs, across_pairs, baseline_targets, unavailable
from miktcli.studies.grid import Grid
from miktcli.studies.random_cache import CACHE_FILE, study_random_returns
from miktcli.studies.render_figures import write_figures
from miktcli.studies.render_json import write_json
from miktcli.studies.render_markdown import render_markdown
from miktcli.studies.render_tensorboard import write_tensorboard_tree
from miktcli.studies.summary import RunOf, StudySummary, summarise


class Report(NamedTuple):
    path: Path
    left_out: list[str]  # completed runs whose files could not be used, each with the reason


def study_across_pairs(summary: StudySummary, out_dir: Path) -> AcrossPairs:
    """The across-pairs section, its random-policy returns from the study folder's cache (measuring the
    targets it lacks), or the reason it has no numbers."""
    if not summary.grid.random_returns:
        return unavailable(summary, "the grid says `random_returns = false`")
    targets = baseline_targets(summary)
    if not targets:  # nothing to measure: across_pairs says why there are no numbers
        return across_pairs(summary, {}, CACHE_FILE)
    try:
        random = study_random_returns(out_dir, targets, summary.grid.name)
    except MiktError as err:  # a damaged cache, or a target that cannot be made: said in the section
        return unavailable(summary, f"no random-policy returns: {err}", CACHE_FILE)
    return across_pairs(summary, random, f"{CACHE_FILE} in this folder")


def write_report(grid: Grid, out_dir: Path, cell_runs: dict[str, str], run_of: RunOf) -> Report:
    """results.md (the numbers across pairs, then tables and comparisons per pair), summary.json,
    comparisons.json, the curve, student-weight and profile plots and the TensorBoard tree, all from one
    summary of the finished runs."""
    out_dir.mkdir(parents=True, exist_ok=True)
    summary = summarise(grid, cell_runs, run_of)
    summary = dataclasses.replace(summary, across_pairs=study_across_pairs(summary, out_dir))
    write_figures(summary, out_dir)
    write_tensorboard_tree(grid, out_dir / "tensorboard", run_of)
    path = out_dir / "results.md"
    write_text_atomic(path, render_markdown(summary))
    write_json(summary, out_dir)
    return Report(path, summary.left_out)
