"""A study's figures from its summary: each pair's learning curves (mean ± sample std over seeds) and student
weights, every pair at a glance (summary.png) when the study has more than one, and the performance profiles
across pairs (aggregate-profile.png), which the across-pairs section (studies.sections) draws."""

from __future__ import annotations

from pathlib import Path

from miktcli.methods.mixing import is_teacher_key
from miktcli.stats.plots import png_panels, png_performance_profiles, png_plot
from miktcli.studies.aggregates import PROFILE_MEASURE, AcrossPairs
from miktcli.studies.summary import PairSummary, StudySummary, partial_seed_labels

SUMMARY_FIGURE = "summary.png"
PROFILE_FIGURE = "aggregate-profile.png"


def curves_file(pair: PairSummary) -> str:
    return f"curves-{pair.slug}.png"


def weights_file(pair: PairSummary) -> str:
    return f"weights-{pair.slug}.png"


def draws_summary(summary: StudySummary) -> bool:
    """The figure for a README: only for a study of several pairs with curves."""
    return sum(bool(pair.with_runs) for pair in summary.pairs) > 1


def _curve_panel(pair: PairSummary):
    methods = pair.with_runs
    series = {m.name: m.curve() for m in methods}
    bands = {m.name: m.band() for m in methods}
    return series, bands, partial_seed_labels({m.name: m.n for m in methods}, {m.name: m.planned for m in methods})


def write_weight_panels(pair: PairSummary, weighted: list, out_dir: Path) -> Path:
    """Several methods' weights: one panel per method, each weight named alone (the method is the panel's
    title), so a weight keeps its colour from panel to panel. All of them on one set of axes (a screening of
    eight two-teacher methods has 96 curves) could not be read, and its legend outgrew the axes."""
    panels, labels = [], []
    for m in weighted:
        series = {key.removeprefix(f"{m.name} "): curve for key, curve in m.weight_curves.items()}
        panels.append((series, f"{m.name}: student weights", None))
        labels.append(partial_seed_labels(dict.fromkeys(series, m.n), m.planned))
    teachers = any(is_teacher_key(key) for series, _, _ in panels for key in series)
    ylabel = "weight (p: the student, w: each teacher)" if teachers else "p (student)"
    return png_panels(panels, out_dir / weights_file(pair), ylabel, labels=labels)


def write_profiles(across: AcrossPairs, out_dir: Path, title: str) -> Path | None:
    """The performance profiles of the across-pairs section, where it has them."""
    if not across.profiles:
        return None
    profiles = {p.name: (p.thresholds, p.fraction, p.low, p.high) for p in across.profiles}
    return png_performance_profiles(profiles, out_dir / PROFILE_FIGURE,
                                    f"{title}: performance profiles ({PROFILE_MEASURE}, normalised; 95 % bands)")


def write_figures(summary: StudySummary, out_dir: Path) -> None:
    order = [m.name for m in summary.grid.methods]  # each method keeps its colour in every figure
    panels, panel_labels = [], []
    for pair in summary.pairs:
        if pair.with_runs:
            series, bands, labels = _curve_panel(pair)
            panels.append((series, pair.name, bands))
            panel_labels.append(labels)
            png_plot(series, out_dir / curves_file(pair), pair.name, "mean episode return", bands, order, labels)
        weighted = [m for m in pair.methods if m.weight_curves]
        if len(weighted) == 1:
            m = weighted[0]
            png_plot(m.weight_curves, out_dir / weights_file(pair), f"{pair.name}: student weights", "p (student)",
                     labels=partial_seed_labels(dict.fromkeys(m.weight_curves, m.n), m.planned))
        elif weighted:
            write_weight_panels(pair, weighted, out_dir)
    if draws_summary(summary):
        png_panels(panels, out_dir / SUMMARY_FIGURE, "mean episode return", order=order, labels=panel_labels)
