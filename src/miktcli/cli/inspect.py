"""`mikt inspect`: a run's card, mixing weights and learning curve, or a teacher's card."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from miktcli.cli.cards import render_card
from miktcli.cli.common import DEFAULT_REGISTRY, JsonOption, RegistryOption
from miktcli.cli.console import err, out, print_json

HELP = """Inspect a run (runN) or a teacher (NAME or NAME@vN); with no target, the newest run (last).

Examples:

  mikt inspect --curve

  mikt inspect run1 --coupling

  mikt inspect run1 --curve --plot curve.png

  mikt inspect run1 --json

  mikt inspect centipede-four@v1
"""


def _is_run(target: str) -> bool:
    from miktcli.registry.runs import RUN_TARGET_RE

    return bool(RUN_TARGET_RE.fullmatch(target))


def _sampled(rows: list[dict], n: int) -> list[dict]:
    if len(rows) <= n:
        return rows
    idx = sorted({round(i * (len(rows) - 1) / (n - 1)) for i in range(n)})
    return [rows[i] for i in idx]


def inspect(
    target: str = typer.Argument("last", help="runN, last (the newest run) or a teacher NAME or NAME@vN.",
                                 show_default=True),
    coupling: bool = typer.Option(
        False, "--coupling", help="Every source's mixing weight (student, each teacher) per layer over training."),
    curve: bool = typer.Option(False, "--curve", help="The learning curve (mean return over training)."),
    plot: Path = typer.Option(None, "--plot", help="Also write the chosen view as a PNG."),
    rows: int = typer.Option(12, "--rows", min=2, help="Table rows to show."),
    as_json: JsonOption = False,
    registry: RegistryOption = DEFAULT_REGISTRY,
) -> None:
    from miktcli.errors import MiktError
    from miktcli.methods import METHODS
    from miktcli.outfiles import prepare_output
    from miktcli.registry.runs import open_run
    from miktcli.stats.plots import png_plot, text_plot

    reg = registry
    if plot and not (coupling or curve):
        raise typer.BadParameter("--plot writes the chosen view: add --coupling or --curve", param_hint="'--plot'")
    if plot:
        prepare_output(plot)
    if not _is_run(target):
        from miktcli.registry.teachers import load_teacher

        teacher = load_teacher(reg, target)
        card = {**teacher.card.model_dump(mode="json"), "source": teacher.source, "path": str(teacher.path)}
        print_json(card) if as_json else render_card(card)
        return
    run = open_run(reg, target)
    metrics = run.read_metrics()
    if run.damaged_metric_lines:
        err.print(f"warning: skipped {run.damaged_metric_lines} damaged line(s) in {run.metrics_path}")
    if as_json:
        print_json({"card": {**run.card.model_dump(mode="json"), "status": run.status},
                    "kept_checkpoints": run.kept_checkpoints(), "metrics": metrics})
        return
    if not (coupling or curve):
        # kept checkpoints: the points `mikt transfer --branch RUN --at NAME` can start from
        render_card({**run.card.model_dump(mode="json", exclude={"config"}), "status": run.status,
                     "kept_checkpoints": ", ".join(run.kept_checkpoints()) or "none"})
        err.print("Hint: --coupling for the mixing weights, --curve for the learning curve, --json for all.")
        return
    if coupling:
        from miktcli.methods.mixing import mixing_series
        from miktcli.stats.plots import png_panels

        names = [t.name for t in run.card.teachers]
        if len(set(names)) < len(names):  # the same teacher in two versions: tell them apart
            names = [f"{t.name}@v{t.version}" for t in run.card.teachers]
        branches = mixing_series(metrics, names)
        if not branches:
            method = METHODS.get(run.card.method)
            mixing = [name for name, m in METHODS.items() if m.mixes_teachers]
            raise MiktError(f"run '{run.id}' has no mixing weights yet: it has no metrics"
                            if method is not None and method.mixes_teachers and not metrics
                            else f"run '{run.id}' ({run.card.method}) has no mixing weights: only "
                                 f"{', '.join(mixing)} runs do")
        shown = _sampled(metrics, rows)
        for branch, series in branches.items():
            by_step = {label: dict(points) for label, points in series.items()}
            table = Table("steps", *series, "teacher", title=f"{branch}: weight of each source per layer")
            for r in shown:
                values = [by_step[label].get(r["steps"]) for label in series]
                table.add_row(f"{r['steps']:,}", *("—" if v is None else f"{v:.3f}" for v in values),
                              "on" if r.get("teacher_active", 1.0) else "dropped")
            out.print(table)
            out.print(text_plot(series, y_range=(0.0, 1.0)))
        if plot:
            png_panels([(series, f"{run.id}: {branch} mixing weights", None) for branch, series in branches.items()],
                       plot, "weight", columns=2)
            err.print(f"wrote {plot}")
    if curve:
        table = Table("steps", "mean return (last 100 ep.)", "mean length", "steps/s")
        for r in _sampled(metrics, rows):
            ret, length, sps = (r.get(k) for k in ("return_mean", "length_mean", "steps_per_sec"))
            table.add_row(f"{r['steps']:,}", "—" if ret is None else f"{ret:.1f}",
                          "—" if length is None else f"{length:.0f}", "—" if sps is None else f"{sps:.0f}")
        out.print(table)
        series = {"return": [(r["steps"], r["return_mean"]) for r in metrics if r.get("return_mean") is not None]}
        out.print(text_plot(series))
        if plot and not coupling:
            png_plot(series, plot, f"{run.id}: {run.card.method} on {run.card.env}", "mean episode return")
            err.print(f"wrote {plot}")
