"""The study report: one summary of the finished runs (studies.summary), its sections (studies.sections:
the standard ones and those the grid asks for), then the renderers: results.md, summary.json and
comparisons.json, the figures and the TensorBoard tree."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

from miktcli.registry.files import write_text_atomic
from miktcli.studies.grid import Grid
from miktcli.studies.render_figures import write_figures
from miktcli.studies.render_json import write_json
from miktcli.studies.render_markdown import render_markdown
from miktcli.studies.render_tensorboard import write_tensorboard_tree
from miktcli.studies.sections import render_sections, section_data
from miktcli.studies.summary import RunOf, summarise


class Report(NamedTuple):
    path: Path
    left_out: list[str]  # completed runs whose files could not be used, each with the reason


def write_report(grid: Grid, out_dir: Path, cell_runs: dict[str, str], run_of: RunOf) -> Report:
    """results.md (the intro, the sections, the runs), summary.json, comparisons.json, the curve,
    student-weight and profile plots and the TensorBoard tree, all from one summary of the finished runs."""
    out_dir.mkdir(parents=True, exist_ok=True)
    summary = summarise(grid, cell_runs, run_of)
    sections = render_sections(summary, out_dir)
    write_figures(summary, out_dir)
    write_tensorboard_tree(grid, out_dir / "tensorboard", run_of)
    path = out_dir / "results.md"
    write_text_atomic(path, render_markdown(summary, [rendered.markdown for _, rendered in sections]))
    write_json(summary, out_dir, section_data(sections))
    return Report(path, summary.left_out)
