"""A study's method beside a reference result (studies.reference), as Markdown: pair by pair in the reference's
windows and at the study's marks, each branch's student weight during the coupling ramp, and the hand-over at
the teacher drop, ours and the reference's, measured alike. `label` names the reference (e.g. "CAT")."""

from __future__ import annotations

import numpy as np

from miktcli.registry.runs import Run
from miktcli.studies.grid import Grid
from miktcli.studies.reference import Reference, across_drop, branch_weight_at, hand_over, window_mean
from miktcli.studies.summary import MethodSummary, StudySummary, mean_pm_std


def method_of(summary: StudySummary, pair_name: str, method: str) -> MethodSummary:
    pair = next(p for p in summary.pairs if p.name == pair_name)
    return next(m for m in pair.methods if m.name == method)


def at_step(m: MethodSummary, step: int) -> float:
    """The seed-mean curve at the last iteration at or before `step` (NaN before the first)."""
    i = int(np.searchsorted(m.steps, step, side="right")) - 1
    return float(m.mean[i]) if i >= 0 else float("nan")


def whole(value: float) -> str:
    return "—" if not np.isfinite(value) else f"{value:,.0f}"


def returns_pm(values: list[float]) -> str:
    """Returns: mean ± sample std of the finite ones, in whole units."""
    finite = [v for v in values if np.isfinite(v)]
    return mean_pm_std(np.array(finite)) if finite else "—"


def _mean_sd(values: list[float], mean_format: str, sd_format: str | None = None) -> str:
    """mean ± sample std in the given formats; one value alone."""
    if len(values) == 1:
        return format(values[0], mean_format)
    return f"{format(np.mean(values), mean_format)} ± {format(np.std(values, ddof=1), sd_format or mean_format)}"


def changes_pm(values: list[float]) -> str:
    """Changes, signed, in whole units."""
    return _mean_sd(values, "+,.0f", ",.0f")


def weights_pm(values: list[float]) -> str:
    """Weights, with two decimals."""
    return _mean_sd(values, ".2f")


def window_label(window: tuple[int, int]) -> str:
    return f"{window[0] / 1e6:g}–{window[1] / 1e6:g}M"


def _in_windows(m: MethodSummary, reference: Reference) -> list[str]:
    rows = [r.read_metrics() for r in m.runs]
    return [returns_pm([window_mean(r, lo, hi) for r in rows]) for lo, hi in reference.windows]


def _trend(m: MethodSummary, fall: tuple[int, int]) -> tuple[bool, str]:
    start, stop = at_step(m, fall[0]), at_step(m, fall[1])
    between = m.mean[(m.steps >= fall[0]) & (m.steps <= fall[1])]
    fell = stop < start
    return fell, (f"{whole(start)} → {whole(stop)} ({'falls' if fell else 'no fall'}; "
                  f"{whole(float(np.min(between))) if between.size else '—'})")


def window_lines(grid: Grid, summary: StudySummary, reference: Reference, method: str, label: str,
                 fall: tuple[int, int] | None = None) -> list[str]:
    """Pair by pair: ours with the reference's estimator beside its figure in each window; then ours with the
    study's estimator at the marks, the gap at the end and whether it reaches the reference, and (with
    `fall`) the seed-mean curve between two steps."""
    marks = [m for m in grid.marks if m <= grid.steps]
    last = window_label(reference.windows[-1])
    head = ["teachers → target", "n",
            *(f"{who} {window_label(w)}" for w in reference.windows for who in ("ours", label))]
    windows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    fall_head = f" mean curve {fall[0] / 1e6:g}M → {fall[1] / 1e6:g}M (lowest between) |" if fall else ""
    end = ["| teachers → target | n | " + " | ".join(f"ours at {m / 1e6:g}M" for m in marks)
           + f" | {label} {last} | ours − {label} at {grid.steps / 1e6:g}M | reaches {label} |" + fall_head,
           "|" + "---|" * (len(marks) + (6 if fall else 5))]
    reached, compared, falls = 0, 0, 0
    for pair in grid.pairs:
        m = method_of(summary, pair.name, method)
        ref = reference.run_for(pair.teacher_names, pair.to)
        theirs = [whole(x) for x in ref.returns] if ref else ["—"] * len(reference.windows)
        windows.append(f"| {pair.name} | {m.n} | " + " | ".join(
            c for cells in zip(_in_windows(m, reference), theirs, strict=True) for c in cells) + " |")
        if not m.runs:
            end.append(f"| {pair.name} | 0 | " + " | ".join(["—"] * len(marks) + [theirs[-1], "—", "—"]
                                                           + (["—"] if fall else [])) + " |")
            continue
        at_marks = [mean_pm_std(m.curves[:, i]) if (i := int(np.searchsorted(m.steps, mark, "right")) - 1) >= 0
                    else "—" for mark in marks]
        final = float(np.mean(m.curves[:, -1]))
        verdict, gap = "—", "—"
        if ref:
            compared += 1
            gap = f"{final - ref.returns[-1]:+,.0f}"
            verdict = "yes" if final >= ref.returns[-1] else "no"
            reached += final >= ref.returns[-1]
        row = f"| {pair.name} | {m.n} | " + " | ".join(at_marks) + f" | {theirs[-1]} | {gap} | {verdict} |"
        if fall:
            fell, trend = _trend(m, fall)
            falls += fell
            row += f" {trend} |"
        end.append(row)
    done = [p for p in grid.pairs if method_of(summary, p.name, method).n]
    full = all(m.n == m.planned for m in (method_of(summary, p.name, method) for p in grid.pairs))
    fall_text = (f" The last column is the seed-mean curve at {fall[0] / 1e6:g}M and {fall[1] / 1e6:g}M and its "
                 "lowest value between them." if fall else "")
    fall_count = (f"; the mean curve falls between {fall[0] / 1e6:g}M and {fall[1] / 1e6:g}M on {falls}"
                  if fall else "")
    return [
        f"## `{method}` against {label}, pair by pair", "",
        f"`{method}` of `{grid.name}`, completed seeds only (n of the seeds the grid plans for the pair). {label}: "
        f"{reference.estimator}.", "",
        f"**{label}'s estimator.** Ours: each run's `episode_return_iter` (the mean return of the episodes that "
        f"finished in each rollout, {label}'s `eprewmean`) averaged over the iterations in the "
        "window, then mean ± sample std (ddof 1) over seeds.", "", *windows, "",
        "**The study's estimator.** Ours: the mean training return over the last 100 "
        "episodes at each mark (the last iteration at or before it), mean ± sample std over seeds. \"Reaches "
        f"{label}\": the seed mean at {grid.steps / 1e6:g}M is at least {label}'s {last} figure.{fall_text}", "",
        *end, "",
        f"Reaches {label} on **{reached} of {compared}** pairs with completed seeds ({len(done)} of "
        f"{len(grid.pairs)} pairs have any){fall_count}. "
        + ("Every pair has all its seeds." if full else
           "Not every pair has all the grid's seeds yet: these are partial results."), ""]


def ramp_lines(grid: Grid, summary: StudySummary, reference: Reference, method: str, label: str) -> list[str]:
    """Ours beside the reference: each branch's student weight at marks inside the coupling ramp."""
    if not reference.ramp_marks:
        return []
    marks = reference.ramp_marks
    head = ["teachers → target", "branch", "n", *(f"{who} {m / 1e6:g}M" for m in marks for who in ("ours", label))]
    lines = ["### The student weights during the ramp", "",
             "The student weight p of each branch (π: policy, V: value function), averaged over its hidden layers "
             f"as {label} logs it, at the last iteration at or before each mark; ours mean ± sample std over "
             f"seeds. 1 is the teachers unused: the coupling loss pushes p towards it.", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for pair in grid.pairs:
        m = method_of(summary, pair.name, method)
        ref = reference.run_for(pair.teacher_names, pair.to)
        rows = [r.read_metrics() for r in m.runs]
        for branch, name in (("pi", "π"), ("vf", "V")):
            ours = [weights_pm(v) if (v := [x for x in (branch_weight_at(r, s, branch) for r in rows)
                                            if np.isfinite(x)]) else "—" for s in marks]
            theirs = [f"{x:.2f}" for x in ref.ramp.branch(branch)] if ref and ref.ramp else ["—"] * len(marks)
            lines.append(f"| {pair.name} | {name} | {len(rows)} | "
                         + " | ".join(c for cells in zip(ours, theirs, strict=True) for c in cells) + " |")
    return [*lines, ""]


def hand_over_lines(grid: Grid, summary: StudySummary, method: str) -> list[str]:
    """Our runs at the last iteration with the teachers, and what their return does after it."""
    lines = ["### The hand-over at the teacher drop", "",
             f"`{method}`'s completed runs at the last iteration that trained with the teachers: the smallest "
             "student weight p over the layers of policy and value (1: the teachers unused), and the return "
             "(last 100 episodes) there, at its lowest after the drop and at the end; mean ± sample std over "
             "seeds. A student that still leans on its teachers when they go loses what they gave.", "",
             "| teachers → target | n | drop at | smallest p at the drop | return at the drop | lowest after | "
             "at the end | teacher-free eval at the end |", "|---|---|---|---|---|---|---|---|"]
    for pair in grid.pairs:
        m = method_of(summary, pair.name, method)
        found = [(h, e) for h, e in zip(map(hand_over, m.runs), m.evals, strict=True) if h is not None]
        if not found:
            lines.append(f"| {pair.name} | 0 | — | — | — | — | — | — |")
            continue
        drop = ", ".join(f"{s:,}" for s in sorted({h.step for h, _ in found}))
        lines.append(f"| {pair.name} | {len(found)} | {drop} | "
                     f"{weights_pm([h.lowest_weight for h, _ in found])} | "
                     f"{returns_pm([h.at_drop for h, _ in found])} | "
                     f"{returns_pm([h.lowest_after for h, _ in found])} | "
                     f"{returns_pm([h.at_end for h, _ in found])} | {returns_pm([float(e) for _, e in found])} |")
    return [*lines, ""]


def _drops(runs: list[Run], before: int):
    return [h for h in (across_drop(r.read_metrics(), before) for r in runs) if h is not None]


def across_drop_lines(grid: Grid, summary: StudySummary, reference: Reference, method: str, label: str) -> list[str]:
    """Ours beside the reference at the drop, with the measures its logs have."""
    if reference.hand_over_before is None:
        return []
    before = reference.hand_over_before
    lines = [f"**Across the drop, as {label}'s logs measure it.** The student weight p at the last update with the "
             "teachers, averaged over the hidden layers of the policy (π) and of the value function (V), as "
             f"{label} logs it. The return: the mean per-update return (our `episode_return_iter`) over the "
             f"{before:,} steps up to the drop and over every update after it; the change is after − before per "
             "run. Ours: mean ± sample std over seeds.", "",
             f"| teachers → target | n | ours p π / V | {label} p π / V | ours before → after | ours change | "
             f"runs that fall | {label} before → after | {label} change |", "|---|---|---|---|---|---|---|---|---|"]
    for pair in grid.pairs:
        ours = _drops(method_of(summary, pair.name, method).runs, before)
        ref = reference.run_for(pair.teacher_names, pair.to)
        c = ref.hand_over if ref else None
        theirs = ([f"{c.p_pi:.2f} / {c.p_vf:.2f}", f"{whole(c.before)} → {whole(c.after)}",
                   f"{c.after - c.before:+,.0f}"] if c else ["—"] * 3)
        if ours:
            change = [h.after - h.before for h in ours]
            mine = [f"{weights_pm([h.p_pi for h in ours])} / {weights_pm([h.p_vf for h in ours])}",
                    f"{returns_pm([h.before for h in ours])} → {returns_pm([h.after for h in ours])}",
                    changes_pm(change), f"{sum(d < 0 for d in change)} of {len(change)}"]
        else:
            mine = ["—"] * 4
        lines.append(f"| {pair.name} | {len(ours)} | {mine[0]} | {theirs[0]} | {mine[1]} | "
                     f"{mine[2]} | {mine[3]} | {theirs[1]} | {theirs[2]} |")
    return [*lines, ""]


def reference_lines(grid: Grid, summary: StudySummary, reference: Reference, method: str, label: str,
                    fall: tuple[int, int] | None = None) -> list[str]:
    """Every part against the reference, in the order a reader wants them: the returns, the ramp, the drop."""
    return [*window_lines(grid, summary, reference, method, label, fall),
            *ramp_lines(grid, summary, reference, method, label),
            *hand_over_lines(grid, summary, method),
            *across_drop_lines(grid, summary, reference, method, label)]
