"""results.md from a study's summary: per-pair tables (marks, mean over training, final eval, steps to the
baseline), each pair's comparisons over seeds, the figures' links, and the table of every cell's run."""

from __future__ import annotations

import math
from typing import Any

from miktcli.methods.mixing import student_layers
from miktcli.registry.cards import describe_code_history
from miktcli.registry.runs import Run
from miktcli.stats.across_tasks import Estimate
from miktcli.studies.aggregates import MEASURES, PROFILE_MEASURE, PROFILE_RESAMPLES, SEED, AcrossPairs, MeasureAggregate
from miktcli.studies.grid import Grid
from miktcli.studies.render_figures import PROFILE_FIGURE, SUMMARY_FIGURE, curves_file, draws_summary, weights_file
from miktcli.studies.summary import MethodSummary, PairSummary, StudySummary, mean_pm_std


def comparison_lines(rows: list[dict[str, Any]]) -> list[str]:
    """The comparisons over seeds (rows of `compare_methods`) as a Markdown section; none without rows."""
    if not rows:
        return []
    lines = []
    for c in rows:
        p = f"{c['p_value']:.3f}" + ("" if c["exact"] else " (Monte Carlo)")
        lines.append(f"| {c['a']} vs {c['b']} | {c['n_a']} / {c['n_b']} | {c['measure']} | {c['difference']:+,.0f} | "
                     f"{c['p_improvement']:.2f} | {p} | {c['smallest_p']:.3f} |")
    header = ["", "### Comparisons over seeds", "",
              "A − B is the difference of the seed means; P(A > B) the fraction of seed pairs in which A is higher "
              "(ties half); p the two-sided permutation test of the difference (every split of the pooled seeds), "
              "which cannot go below the floor its seed counts allow.", "",
              "| A vs B | n (A / B) | measure | A − B | P(A > B) | p | smallest possible p |",
              "|---|---|---|---|---|---|---|"]
    return header + lines


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


def _method_row(m: MethodSummary, pair: PairSummary, columns: int) -> str:
    if not m.runs:
        return f"| {m.name} | 0 | " + " | ".join("—" for _ in range(columns)) + " |"
    mean = m.mean
    cells = ["—" if i < 0 or i >= len(mean) or math.isnan(mean[i]) else mean_pm_std(m.curves[:, i])
             for i in pair.marks.values()]
    weights = "—"
    if m.final_weights is not None:
        pi = "/".join(f"{v:.2f}" for v in student_layers(m.final_weights, "pi"))
        vf = "/".join(f"{v:.2f}" for v in student_layers(m.final_weights, "vf"))
        weights = f"{pi} · {vf}"
    return (f"| {m.name} | {m.n} | " + " | ".join(cells) + f" | {mean_pm_std(m.mean_over_training)} | "
            f"{mean_pm_std(m.evals)} | {m.reach} | {m.reach_75} | {weights} |")


def pair_lines(pair: PairSummary, baseline: str) -> list[str]:
    header = ["method", "n", *pair.mark_labels, "mean over training",
              "final eval (no teacher)", f"steps to {baseline} final", f"steps to ¾ of {baseline} final",
              "final student weights p (π / V)"]
    lines = [f"## {pair.name}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += [_method_row(m, pair, len(header) - 2) for m in pair.methods]
    lines += comparison_lines(pair.comparisons)
    if pair.with_runs:
        lines += ["", f"![learning curves]({curves_file(pair)})"]
    if any(m.weight_curves for m in pair.methods):
        lines += ["", f"![student weights]({weights_file(pair)})"]
    return [*lines, ""]


def _intro(summary: StudySummary) -> list[str]:
    g = summary.grid
    lines = [f"# Study `{g.name}`", ""]
    if summary.left_out:  # said at the top: these runs finished but their numbers are in no table below
        lines += ["**Completed runs left out** (their files are incomplete; restore them from a snapshot or "
                  "train the cells again):", "", *(f"- {problem}" for problem in summary.left_out), ""]
    failed = [(key, run_id, run.card.error or "no error recorded") for key, run_id, run in summary.cells
              if run is not None and run.card.status == "failed"]
    if failed:  # also at the top: a study with a failed cell is not finished, whatever its tables show
        lines += ["**Failed cells** (their runs stopped with an error; running the study again retries them):", "",
                  *(f"- {key}: {run_id}: {error}" for key, run_id, error in failed), ""]
    if draws_summary(summary):
        lines += [f"![every pair]({SUMMARY_FIGURE})", ""]
    return lines + [
        f"{g.steps:,} steps per run, seeds {g.seeds}{_own_seeds(g)}, {g.eval_episodes} evaluation episodes per run. "
        "Returns are the mean training-episode return over the last 100 episodes at each mark (the last "
        "iteration at or before it: the column names that step), then mean ± sample std (ddof 1) over "
        "the n completed seeds; *mean over training* averages that curve over the whole run (area under "
        "the curve per step); *final eval* is the teacher-free student, deterministic, on fresh seeds. "
        f"*¾ of {g.baseline} final* is the level a quarter of |final| below the baseline's final return "
        "(0.75 × final when it is positive).",
        "", *_teacher_lines(summary)]


def _own_seeds(grid: Grid) -> str:
    own = [f"{p.name}: {p.seeds}" for p in grid.pairs if p.seeds is not None]
    return f" (with teachers, pairs of their own seeds: {'; '.join(own)})" if own else ""


def _teacher_lines(summary: StudySummary) -> list[str]:
    """Which teacher version each grid reference meant: one per reference (pinned when the study was first
    prepared), or every version where a study prepared before pinning mixed them."""
    if not summary.teachers:
        return []
    parts = []
    for ref, versions in summary.teachers.items():
        if len(versions) == 1:
            parts.append(f"`{ref}` → {versions[0].ref} (sha256 {versions[0].sha256[:12]})")
            continue
        described = []
        for v in versions:
            runs = ", ".join(v.runs[:5]) + (f" and {len(v.runs) - 5} more" if len(v.runs) > 5 else "")
            described.append(f"{v.ref} (sha256 {v.sha256[:12]}; {runs})")
        parts.append(f"`{ref}` → **mixed versions**: " + ", ".join(described))
    return ["Teachers: " + "; ".join(parts) + ".", ""]


def _runs_section(summary: StudySummary) -> list[str]:
    lines = ["## Runs", "", "Cells without teachers (`-`) are one run shared by every pair with that target. "
             "*state* is the run's when this report was written; *final train return* the mean over the last 100 "
             "training episodes; the evals are deterministic, on fresh seeds (mean ± std over episodes). "
             "`tensorboard --logdir tensorboard` (in this folder) shows every run, grouped pair / method / seed.", "",
             "| cell (teachers > target) | method | seed | run | state | final train return | eval (no teacher) "
             "| eval (with teacher) | trained by (commit from step) |",
             "|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {' | '.join(key.split('|'))} | {run_id} | {run_row(run)} |" for key, run_id, run in summary.cells]
    return lines


def _estimate(e: Estimate) -> str:
    return f"{e.value:.2f} [{e.low:.2f}, {e.high:.2f}]"


def _measure_lines(m: MeasureAggregate, baseline: str, pairs: list[str]) -> list[str]:
    lines = [f"### {m.measure[0].upper()}{m.measure[1:]}", "",
             f"Score: {MEASURES[m.measure]}, normalised by the same measure of `{baseline}`.", "",
             "| method | runs | pairs | IQM [95 % CI] | mean [95 % CI] |", "|---|---|---|---|---|"]
    lines += [f"| {a.name} | {a.runs} | {a.pairs} | {_estimate(a.iqm)} | {_estimate(a.mean)} |" for a in m.methods]
    if m.improvements:
        lines += ["", "| X vs Y | P(X > Y) [95 % CI] | pairs |", "|---|---|---|"]
        lines += [f"| {i.x} vs {i.y} | {_estimate(i.estimate)} | {i.pairs} |" for i in m.improvements]
    if m.matched:
        lines += ["", "More teachers against fewer on the same tasks: each pair with several teachers against its "
                  "first teacher alone on the same target (the same method and configuration); IQM over those "
                  "tasks, 95 % stratified bootstrap intervals.", "",
                  "| X vs Y | tasks | IQM of X [95 % CI] | IQM of Y [95 % CI] | intervals overlap "
                  "| P(X > Y) [95 % CI] |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| {c.x} vs {c.y} | {c.tasks} | {_estimate(c.x_iqm)} | {_estimate(c.y_iqm)} | "
                  f"{'yes' if c.intervals_overlap else 'no'} | {_estimate(c.improvement)} |" for c in m.matched]
    names = [a.name for a in m.methods]
    lines += ["", "Per pair (IQM of its runs, normalised):", "",
              "| pair | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for pair in pairs:
        cells = [f"{m.per_pair[pair][n]:.2f}" if n in m.per_pair.get(pair, {}) else "—" for n in names]
        lines.append(f"| {pair} | " + " | ".join(cells) + " |")
    return [*lines, ""]


def across_pairs_lines(a: AcrossPairs) -> list[str]:
    """The "Across pairs" section: the normalisation, each measure's IQM and mean with their intervals, the
    probability of improvement, per-pair IQMs and the profiles' figure; or why it has no numbers."""
    base = a.baseline
    lines = ["## Across pairs", ""]
    if a.missing:
        return [*lines, f"No aggregates across pairs: {a.missing}.", *_note_lines(a.notes), ""]
    task = "target" if a.baseline_from_scratch else "pair"
    shared = (f" `{base}` has the same runs on every pair of its target, so its IQM and mean count them once, "
              "per target." if a.baseline_from_scratch else
              f" `{base}` trains with teachers, so each pair has its own scale, and 1 is that method, not PPO from "
              "scratch.")
    scratch = " (PPO from scratch)" if a.baseline_from_scratch else ""
    lines += [f"Each completed run's score is normalised on its {task}, `(R − R_random) / (R_{base} − R_random)`: "
              f"0 is the uniform-random policy, 1 is `{base}`{scratch} "
              f"at the same budget ({a.steps:,} steps), R_{base} "
              f"the mean of its completed runs on that {task}. Tasks are the {len(a.pairs)} pairs.{shared} IQM: "
              "the 25 % trimmed mean over all runs × pairs pooled; intervals: 95 % percentile stratified "
              f"bootstrap (each pair's runs resampled within the pair; {a.n_resamples:,} resamples, seed {SEED}); "
              "probability of improvement: per pair the Mann–Whitney U / (n_x n_y), averaged over pairs "
              f"(Agarwal et al. 2021). Random-policy returns: {a.random_source}.", "",
              *_note_lines(a.notes),
              "### Normalisation", "",
              "R_random, the zero, is the uniform policy over the action box. R_initial is the policy PPO starts "
              "from (N(0, 1) on every action dimension, unclipped), shown for the reader: it is not a scale.", "",
              f"| {task} | R_random (uniform) | R_initial (N(0, 1)) | R_{base} (final return) | n |",
              "|---|---|---|---|---|"]
    for n in a.normalisation:
        rand = "—" if n.random is None else f"{n.random:,.1f}"
        initial = "—" if n.initial is None else f"{n.initial:,.1f}"
        ref = n.reference.get("final return")
        lines.append(f"| {n.task} | {rand} | {initial} | {'—' if ref is None else f'{ref:,.0f}'} | {n.runs} |")
    lines.append("")
    for m in a.measures:
        lines += _measure_lines(m, base, a.pairs)
    if a.profiles:
        lines += ["### Performance profiles", "", f"![performance profiles]({PROFILE_FIGURE})", "",
                  f"The fraction of runs whose normalised {PROFILE_MEASURE} is above τ, averaged over pairs, with "
                  f"pointwise 95 % stratified bootstrap bands ({PROFILE_RESAMPLES:,} resamples).", ""]
    return lines


def _note_lines(notes: list[str]) -> list[str]:
    return ["Left out:", "", *(f"- {note}" for note in notes), ""] if notes else []


def handover_lines(summary: StudySummary) -> list[str]:
    if not summary.handovers:
        return []
    lines = ["## The hand-over at the teacher drop", "",
             "*with* / *without*: the deterministic return (10-episode mean) of the mixed policy on the last "
             "checkpoint before the drop and of the teacher-free student right after the hand-over, on the same "
             "episodes; *kept* = without / with. *before* / *after*: the mean per-update return (episodes "
             "finished in each rollout) over the 50k steps on each side of the drop.", "",
             "| cell (teachers > target) | method | seed | run | hand-over | at step | with | without | kept | "
             "before | after | change |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for key, f in summary.handovers:
        kept = "—" if f.kept is None else f"{f.kept:.0%}"
        lines.append(f"| {' | '.join(key.split('|'))} | {f.run} | {f.handover} | {f.at_step:,} | "
                     f"{f.with_teachers:,.0f} | {f.without_teachers:,.0f} | {kept} | {f.before:,.0f} | "
                     f"{f.after:,.0f} | {f.change:+,.0f} |")
    return [*lines, "", *handover_pair_lines(summary)]


def _signed(x: float) -> str:
    return "—" if not math.isfinite(x) else f"{x:+,.0f}"


def handover_pair_lines(summary: StudySummary) -> list[str]:
    if not summary.handover_pairs:
        return []
    baseline = summary.grid.baseline
    control = any(h.baseline for h in summary.handover_pairs)  # the baseline trains from scratch
    intro = "Per pair, as seed means: *kept* is the ratio of the seed means of *without* and *with*."
    head = "| pair | method | runs | with | without | kept | before | after | change |"
    if control:
        intro += (f" *{baseline}*: the baseline from scratch on the same target, over the same 50k steps on each "
                  f"side of the step where the others drop their teachers. It drops nothing, so its change is how "
                  f"much the per-update return moves across those windows by itself.")
        head += f" {baseline} runs | {baseline} before | {baseline} after | {baseline} change |"
    lines = [intro, "", head, "|---" * head.count(" | ") + "|---|"]
    for h in summary.handover_pairs:
        kept = "—" if h.kept is None else f"{h.kept:.0%}"
        row = (f"| {h.pair} | {h.method} | {h.runs} | {h.with_teachers:,.0f} | {h.without_teachers:,.0f} | {kept} | "
               f"{h.before:,.0f} | {h.after:,.0f} | {h.change:+,.0f} |")
        if control:
            base = f"{h.baseline_before:,.0f} | {h.baseline_after:,.0f}" if h.baseline_runs else "— | —"
            row += f" {h.baseline_runs} | {base} | {_signed(h.baseline_change)} |"
        lines.append(row)
    return [*lines, ""]


def slowdown_lines(summary: StudySummary) -> list[str]:
    if not summary.slowdowns:
        return []
    lines = ["## Runs whose update slowed as they trained", "",
             "The rolling median (20 iterations) of update time over rollout time reached twice its lowest in "
             "the same phase (a busy machine slows both and cancels out). Such a run took longer than it should "
             "have; what it learned is not affected.", "",
             "| cell (teachers > target) | method | seed | run | phase | from step | factor |",
             "|---|---|---|---|---|---|---|"]
    lines += [f"| {' | '.join(key.split('|'))} | {run_id} | {r['phase']} | {r['step']:,} | {r['factor']:.1f}× |"
              for key, run_id, r in summary.slowdowns]
    return [*lines, ""]


def render_markdown(summary: StudySummary, sections: list[list[str]]) -> str:
    """The intro, the sections' lines (studies.sections) in order, then the table of every cell's run."""
    lines = _intro(summary)
    for section in sections:
        lines += section
    return "\n".join(lines + _runs_section(summary)) + "\n"

