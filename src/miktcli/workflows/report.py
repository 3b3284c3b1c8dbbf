"""The study report: per-pair tables (marks, mean over training, final eval, steps to the baseline), each
pair's method-against-method comparisons over seeds, summary.json and comparisons.json with the same numbers,
and learning-curve and student-weight plots."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from miktcli.plots import png_panels, png_plot
from miktcli.registry.cards import describe_code_history
from miktcli.registry.files import write_bytes_atomic, write_text_atomic
from miktcli.registry.runs import Run
from miktcli.registry.tensorboard import EVENTS_FILE, event_records
from miktcli.stats import compare
from miktcli.workflows.grid import Grid, MethodSpec, PairSpec, cell_key, file_slug

RunOf = Callable[[str], Run | None]  # a cell key → its run, if one was started
PerSeed = dict[str, dict[str, np.ndarray]]  # method → measure → one value per completed seed


def first_reach(steps: np.ndarray, curve: np.ndarray, level: float) -> str:
    hit = np.nonzero(curve >= level)[0]
    return f"{int(steps[hit[0]]):,}" if len(hit) else "not reached"


def three_quarters_level(final: float) -> float:
    """"¾ of the baseline's final return", also for a final return ≤ 0, where 0.75·final would be *above*
    it: the level a quarter of |final| below final (equal to 0.75·final when final > 0)."""
    return final - 0.25 * abs(final)


def sample_std(values: np.ndarray, axis: int | None = None) -> np.ndarray | float:
    """Sample standard deviation (ddof 1); NaN for a single value, where it is undefined."""
    values = np.asarray(values, dtype=float)
    n = values.shape[axis] if axis is not None else values.size
    if n < 2:
        return np.full(np.delete(values.shape, axis), np.nan) if axis is not None else float("nan")
    return np.nanstd(values, axis=axis, ddof=1)


def mean_pm_std(values) -> str:
    values = np.asarray(values, dtype=float)
    std = sample_std(values)
    return f"{np.mean(values):.0f} ± {std:.0f}" if math.isfinite(std) else f"{np.mean(values):.0f}"


def unusable(run: Run, rows: list[dict[str, Any]]) -> str | None:
    """Why a completed run's files cannot stand in the report, or None. Its curve must reach the steps its
    card says it trained, line for line, and its card must hold the teacher-free eval: a metrics file cut
    short or edited would otherwise shift every mark and mean without a word."""
    evaluated = run.card.result.get("eval_without_teacher")
    if not (isinstance(evaluated, dict) and isinstance(evaluated.get("return_mean"), int | float)):
        return f"{run.id}: its card has no teacher-free eval result"
    if run.damaged_metric_lines:
        return f"{run.id}: {run.damaged_metric_lines} damaged line(s) in {run.metrics_path.name}"
    if not rows or rows[-1]["steps"] != run.card.steps_done:
        ends = f"ends at {rows[-1]['steps']:,} steps" if rows else "is empty"
        return f"{run.id}: {run.metrics_path.name} {ends}, the run trained {run.card.steps_done:,}"
    return None


def completed_curves(grid: Grid, run_of: RunOf, pair: PairSpec, method: MethodSpec,
                     left_out: list[str] | None = None) -> tuple[list[Run], np.ndarray, np.ndarray]:
    """Completed runs of a cell group and their return curves on the common iteration grid. A completed run
    whose files are incomplete is left out of both, with the reason appended to `left_out`."""
    runs, curves = [], []
    for seed in grid.seeds:
        run = run_of(cell_key(pair, method, seed))
        if run is None or run.card.status != "completed":
            continue
        rows = run.read_metrics()
        problem = unusable(run, rows)
        if problem:
            if left_out is not None and problem not in left_out:
                left_out.append(problem)
            continue
        runs.append(run)
        curves.append([(r["steps"], np.nan if r["return_mean"] is None else r["return_mean"]) for r in rows])
    if not curves:
        return [], np.zeros(0), np.zeros((0, 0))
    # Runs of one grid share the rollout size, so their curves have the same steps; a shorter one (another
    # batch size) would be cut to the common part, never stretched.
    length = min(len(c) for c in curves)
    steps = np.array([s for s, _ in curves[0][:length]])
    return runs, steps, np.array([[v for _, v in c[:length]] for c in curves])


def partial_seed_labels(counts: dict[str, int], seeds: int) -> dict[str, str]:
    """Legend texts for the curves that average fewer seeds than the grid runs, so that a figure of a study
    under way cannot be read as a finished one (one seed also has no band)."""
    return {name: f"{name} ({n} of {seeds} seeds)" for name, n in counts.items()
            if n < seeds}


def comparison_table(per_seed: PerSeed) -> tuple[list[str], list[dict[str, Any]]]:
    """Every method against every later one (grid order), on each per-seed measure: markdown lines and the
    same rows for comparisons.json. A side with fewer than two values is left out (nothing to test)."""
    lines: list[str] = []
    rows: list[dict[str, Any]] = []
    methods = list(per_seed)
    for i, a in enumerate(methods):
        for b in methods[i + 1:]:
            for measure in per_seed[a]:
                # A run without a value (no episode finished yet) has nothing to compare; n says how many do.
                values_a, values_b = (v[np.isfinite(v)] for v in (per_seed[a][measure], per_seed[b][measure]))
                if len(values_a) < 2 or len(values_b) < 2:
                    continue
                c = compare(values_a, values_b)
                p = f"{c.p_value:.3f}" + ("" if c.exact else " (Monte Carlo)")
                lines.append(f"| {a} vs {b} | {c.n_a} / {c.n_b} | {measure} | {c.difference:+,.0f} | "
                             f"{c.p_improvement:.2f} | {p} | {c.smallest_p:.3f} |")
                rows.append({"a": a, "b": b, "measure": measure, "n_a": c.n_a, "n_b": c.n_b,
                             "difference": c.difference, "p_improvement": c.p_improvement,
                             "p_value": c.p_value, "exact": c.exact, "smallest_p": c.smallest_p})
    if not lines:
        return [], []
    header = ["", "### Comparisons over seeds", "",
              "A − B is the difference of the seed means; P(A > B) the fraction of seed pairs in which A is higher "
              "(ties half); p the two-sided permutation test of the difference (every split of the pooled seeds), "
              "which cannot go below the floor its seed counts allow.", "",
              "| A vs B | n (A / B) | measure | A − B | P(A > B) | p | smallest possible p |",
              "|---|---|---|---|---|---|---|"]
    return header + lines, rows

def _eval_cell(result: dict[str, Any], name: str) -> str:
    ev = result.get(name) or {}
    if not isinstance(ev.get("return_mean"), int | float):
        return "—"
    std = ev.get("return_std")
    return f"{ev['return_mean']:,.0f}" + (f" ± {std:,.0f}" if isinstance(std, int | float) else "")


def run_row(run: Run | None) -> str:
    """A run's cells of the study's run table: state, final returns, which code trained it."""
    if run is None:
        return " | ".join(["missing from the registry", "—", "—", "—", "—"])
    card = run.card
    state = "completed" if card.status == "completed" else f"{run.status}, {card.steps_done:,}/{card.total_steps:,}"
    final = card.result.get("final_train_return") if card.status == "completed" else None
    final = final if isinstance(final, int | float) else None
    code = describe_code_history(card.code_history, card.code_version, trained=card.steps_done > 0)
    return " | ".join([state, "—" if final is None else f"{final:,.0f}",
                       _eval_cell(card.result, "eval_without_teacher"), _eval_cell(card.result, "eval_with_teacher"),
                       code])


class Report(NamedTuple):
    path: Path
    left_out: list[str]  # completed runs whose files could not be used, each with the reason


def write_report(grid: Grid, out_dir: Path, cell_runs: dict[str, str], run_of: RunOf) -> Report:
    """results.md (tables and comparisons per pair), summary.json, comparisons.json and the curve and
    student-weight plots."""
    out_dir.mkdir(parents=True, exist_ok=True)
    g = grid
    lines = [f"# Study `{g.name}`", "",
             f"{g.steps:,} steps per run, seeds {g.seeds}, {g.eval_episodes} evaluation episodes per run. "
             "Returns are the mean training-episode return over the last 100 episodes at each mark (the last "
             "iteration at or before it: the column names that step), then mean ± sample std (ddof 1) over "
             "the n completed seeds; *mean over training* averages that curve over the whole run (area under "
             "the curve per step); *final eval* is the teacher-free student, deterministic, on fresh seeds. "
             f"*¾ of {g.baseline} final* is the level a quarter of |final| below the baseline's final return "
             "(0.75 × final when it is positive).",
             ""]
    summary: dict[str, Any] = {}
    comparisons: dict[str, list[dict[str, Any]]] = {}
    panels, panel_labels = [], []
    method_order = [m.name for m in g.methods]  # each method keeps its colour in every figure
    left_out: list[str] = []
    data_of = {pair.name: {m.name: completed_curves(grid, run_of, pair, m, left_out) for m in g.methods}
               for pair in g.pairs}
    # Every run of a grid logs at the same iteration boundaries, so a pair with no finished run yet labels its
    # marks with another pair's logged steps: all tables then name the same columns.
    grid_steps = next((steps for data in data_of.values() for runs, steps, _ in data.values() if runs), None)
    for pair in g.pairs:
        data = data_of[pair.name]
        base_runs, base_steps, base_curves = data[g.baseline]
        base_final = float(np.nanmean(base_curves[:, -1])) if len(base_runs) else None
        marks = g.marks or [g.steps]  # the grid keeps them within 1…steps
        any_steps = next((steps for runs, steps, _ in data.values() if runs), grid_steps)
        mark_index = {}
        for mark in marks:
            i = int(np.searchsorted(any_steps, mark, side="right")) - 1 if any_steps is not None else -1
            mark_index[mark] = i
        mark_labels = [f"{int(any_steps[i]):,}" if i >= 0 else f"{m:,}" for m, i in mark_index.items()]
        header = ["method", "n", *mark_labels, "mean over training",
                  "final eval (no teacher)", f"steps to {g.baseline} final", f"steps to ¾ of {g.baseline} final",
                  "final student weights p (π / V)"]
        lines += [f"## {pair.name}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        series, bands, weight_series = {}, {}, {}
        weight_counts: dict[str, int] = {}  # runs behind each student-weight curve, for its legend
        per_seed: PerSeed = {}
        summary[pair.name] = {}
        for method in g.methods:
            runs, steps, curves = data[method.name]
            if not runs:
                lines.append(f"| {method.name} | 0 | " + " | ".join("—" for _ in header[2:]) + " |")
                continue
            mean = np.nanmean(curves, 0)
            std = sample_std(curves, axis=0)
            cells = ["—" if i < 0 or i >= len(mean) or math.isnan(mean[i]) else mean_pm_std(curves[:, i])
                     for i in mark_index.values()]
            evals = [r.card.result["eval_without_teacher"]["return_mean"] for r in runs]  # checked by unusable
            reach = reach_75 = "—"
            if base_final is not None:
                reach, reach_75 = (first_reach(steps, mean, level)
                                   for level in (base_final, three_quarters_level(base_final)))
            weights = "—"
            mixing = [r.card.result.get("final_mixing_learned") for r in runs]
            if all(mixing):
                keys = sorted(mixing[0])
                avg = {k: float(np.mean([m[k] for m in mixing])) for k in keys}
                pi = "/".join(f"{avg[k]:.2f}" for k in keys if k.startswith("p_pi"))
                vf = "/".join(f"{avg[k]:.2f}" for k in keys if k.startswith("p_vf"))
                weights = f"{pi} · {vf}"
                rows = [r.read_metrics() for r in runs]
                n = min(len(r) for r in rows)
                for k in keys:
                    weight_series[f"{method.name} {k}"] = [
                        (rows[0][i]["steps"], float(np.mean([r[i][k] for r in rows]))) for i in range(n)]
                    weight_counts[f"{method.name} {k}"] = len(runs)
            # Area under the curve per step: how much return the whole run collected, jump-start included.
            auc = np.nanmean(curves, axis=1)
            per_seed[method.name] = {"final return": curves[:, -1],
                                     "mean over training": auc, "final eval (no teacher)": np.asarray(evals)}
            lines.append(f"| {method.name} | {len(runs)} | " + " | ".join(cells)
                         + f" | {mean_pm_std(auc)} | {mean_pm_std(evals)} | {reach} | {reach_75} | {weights} |")
            series[method.name] = list(zip(steps.tolist(), mean.tolist(), strict=True))
            band = np.nan_to_num(std)  # one seed: no band
            bands[method.name] = list(zip(steps.tolist(), (mean - band).tolist(), (mean + band).tolist(),
                                          strict=True))
            summary[pair.name][method.name] = {
                "runs": [r.id for r in runs], "n": len(runs),
                "final_eval_mean": float(np.mean(evals)), "final_eval_std": _json_number(sample_std(evals)),
                "final_train_mean": float(mean[-1]), "final_train_std": _json_number(std[-1]),
                "marks": {str(int(steps[i])): {"mean": float(mean[i]), "std": _json_number(std[i])}
                          for i in mark_index.values() if 0 <= i < len(mean)},
                "mean_over_training": float(np.mean(auc)), "mean_over_training_std": _json_number(sample_std(auc)),
                "steps_to_baseline_final": reach, "steps_to_three_quarters_of_baseline_final": reach_75,
            }
        compared, comparisons[pair.name] = comparison_table(per_seed)
        lines += compared
        slug = file_slug(pair.name)
        if series:
            labels = partial_seed_labels({name: len(data[name][0]) for name in series}, len(g.seeds))
            panels.append((series, pair.name, bands))
            panel_labels.append(labels)
            png_plot(series, out_dir / f"curves-{slug}.png", pair.name, "mean episode return", bands, method_order,
                     labels)
            lines += ["", f"![learning curves]({f'curves-{slug}.png'})"]
        if weight_series:
            png_plot(weight_series, out_dir / f"weights-{slug}.png", f"{pair.name}: student weights",
                     "p (student)", labels=partial_seed_labels(weight_counts, len(g.seeds)))
            lines += ["", f"![student weights]({f'weights-{slug}.png'})"]
        lines.append("")
    if len(panels) > 1:  # every pair at a glance: the figure for a README
        png_panels(panels, out_dir / "summary.png", "mean episode return", order=method_order,
                   labels=panel_labels)
        lines[2:2] = ["![every pair](summary.png)", ""]
    if left_out:  # said at the top: these runs finished but their numbers are in no table above
        lines[2:2] = ["**Completed runs left out** (their files are incomplete; restore them from a snapshot or "
                      "train the cells again):", "", *(f"- {problem}" for problem in left_out), ""]
        summary["left_out"] = left_out
    write_tensorboard_tree(grid, out_dir / "tensorboard", run_of)
    lines += ["## Runs", "", "Cells without teachers (`-`) are one run shared by every pair with that target. "
              "*state* is the run's when this report was written; *final train return* the mean over the last 100 "
              "training episodes; the evals are deterministic, on fresh seeds (mean ± std over episodes). "
              "`tensorboard --logdir tensorboard` (in this folder) shows every run, grouped pair / method / seed.", "",
              "| cell (teachers > target) | method | seed | run | state | final train return | eval (no teacher) "
              "| eval (with teacher) | trained by (commit from step) |",
              "|---|---|---|---|---|---|---|---|---|"]
    for key, run_id in cell_runs.items():
        lines.append(f"| {' | '.join(key.split('|'))} | {run_id} | {run_row(run_of(key))} |")
    path = out_dir / "results.md"
    write_text_atomic(path, "\n".join(lines) + "\n")
    write_text_atomic(out_dir / "summary.json", json.dumps(summary, indent=2, ensure_ascii=False))
    write_text_atomic(out_dir / "comparisons.json", json.dumps(comparisons, indent=2, ensure_ascii=False))
    return Report(path, left_out)


def _json_number(value: float) -> float | None:
    return float(value) if math.isfinite(float(value)) else None


def write_tensorboard_tree(grid: Grid, folder: Path, run_of: RunOf) -> None:
    """One event file per started cell, under PAIR/METHOD/seedN, made from the run's metrics.jsonl (the
    source of truth), so TensorBoard groups and compares the study's runs. A shared run appears under every
    pair it serves."""
    for pair in grid.pairs:
        for method in grid.methods:
            for seed in grid.seeds:
                run = run_of(cell_key(pair, method, seed))
                if run is None:
                    continue
                target = folder / file_slug(pair.name) / file_slug(method.name) / f"seed{seed}" / EVENTS_FILE
                write_bytes_atomic(target, event_records(run.read_metrics(), wall_time=0.0))
