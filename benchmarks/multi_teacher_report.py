"""Two-teacher MIKT against CAT's published runs, and across studies against one-teacher MIKT and PPO from
scratch (issue 34), from the committed snapshots of two studies.

    PYTHONPATH=src python benchmarks/multi_teacher_report.py benchmarks/results/multi-cat \\
        [--one-teacher benchmarks/results/paper-2m/paper-2m] [--cat benchmarks/reference/cat-uai2022.toml] \\
        [--random benchmarks/results/random-policy.json]

- Pair by pair against CAT: our completed seeds with two estimators, the one of every study report (the mean
  training return over the last 100 episodes at a mark) and CAT's (the mean of each update's `eprewmean`, our
  `episode_return_iter`, over the updates in a window), next to CAT's figure for the same window; and whether
  the seed-mean curve falls between 1M and 1.5M; each branch's student weight at marks inside the coupling
  ramp beside CAT's; and what each run's return does when the schedule drops the
  teachers (the smallest student weight then, the return there, after and at the end), and beside CAT's logs
  across the same drop (the student weight averaged over each branch's layers, the per-update return before
  and after).
- Across studies: every run's score normalised on its target between the random policy (0) and the mean of
  PPO from scratch on that target (1, the two-teacher study's baseline); the IQM and mean with 95 % stratified
  bootstrap intervals for two-teacher MIKT (this study), one-teacher MIKT (the one-teacher study's pairs on the
  same targets) and PPO from scratch; the probability of improvement over the targets two families share; the
  performance profiles (a figure). The one-teacher pairs are other tasks than the two-teacher pairs (one
  teacher, not two), so the IQM strata are pairs and the probability of improvement is taken per target body.

Writes `STUDY/against-cat.md` and `STUDY/against-cat-profile.png` (or `--out FILE` and FILE-profile.png beside
it); reads nothing from the registry. A screening whose baseline is a transfer method, not PPO from scratch, gets
the sections against CAT only: `--method NAME` picks which of its methods.
"""

from __future__ import annotations

import argparse
import json
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from cross_study import snapshot_runs, teachers_of

from miktcli.registry.files import write_text_atomic
from miktcli.registry.runs import Run
from miktcli.stats import across_tasks
from miktcli.stats.plots import png_performance_profiles
from miktcli.studies.grid import Grid, PairSpec, load_grid
from miktcli.studies.summary import MethodSummary, StudySummary, mean_pm_std, summarise

ROOT = Path(__file__).resolve().parents[1]
MEASURES = ("final return", "mean over training")
FALL = (1_000_000, 1_500_000)  # the "no fall between 1M and 1.5M on the mean curve"
SEED = 0
PROFILE_POINTS = 101
PROFILE_RESAMPLES = 2_000

Scores = dict[str, np.ndarray]  # stratum (a pair or a target) → one normalised score per run


@dataclass(frozen=True)
class AcrossDrop:
    """A run across its teacher drop, measured as CAT's logs allow: the student weight p at the last update with
    the teachers, averaged over the layers of each branch (CAT logs the mean), and the mean per-update return
    (`eprewmean`) over a window up to the drop and over everything after it."""

    drop: int
    p_pi: float
    p_vf: float
    before: float
    after: float


@dataclass(frozen=True)
class CatRun:
    teachers: tuple[str, ...]
    to: str
    returns: list[float]  # one per window
    hand_over: AcrossDrop | None = None
    ramp: dict[str, list[float]] | None = None  # "pi" / "vf" → the branch's mean student weight at each ramp mark


@dataclass(frozen=True)
class Cat:
    estimator: str
    windows: list[tuple[int, int]]
    runs: list[CatRun]
    hand_over_before: int | None = None  # steps: the window up to the drop that `before` averages
    ramp_marks: list[int] | None = None

    def run_for(self, teachers: str, to: str) -> CatRun | None:
        return next((r for r in self.runs if "+".join(r.teachers) == teachers and r.to == to), None)


def load_cat(path: Path) -> Cat:
    try:
        doc = tomllib.loads(path.read_text())
        windows = [(int(lo), int(hi)) for lo, hi in doc["windows"]]
        runs = [CatRun(tuple(r["teachers"]), r["to"], [float(x) for x in r["returns"]], _across_drop(r),
                       _ramp(r)) for r in doc["runs"]]
        before = int(doc["hand_over_before"]) if "hand_over_before" in doc else None
        ramp_marks = [int(x) for x in doc["ramp_marks"]] if "ramp_marks" in doc else None
    except (OSError, tomllib.TOMLDecodeError, KeyError, TypeError, ValueError) as e:
        raise SystemExit(f"Error: {path}: not a file of CAT's figures ({e})") from None
    if any(len(r.returns) != len(windows) for r in runs):
        raise SystemExit(f"Error: {path}: every run needs one return per window ({len(windows)})")
    if before is None and any(r.hand_over for r in runs):
        raise SystemExit(f"Error: {path}: runs give a hand_over but the file has no hand_over_before (steps)")
    if any(r.ramp and any(len(v) != len(ramp_marks or []) for v in r.ramp.values()) for r in runs):
        raise SystemExit(f"Error: {path}: every run's ramp needs one student weight per ramp_marks entry")
    return Cat(str(doc.get("estimator", "")), windows, runs, before, ramp_marks)


def _ramp(doc: dict) -> dict[str, list[float]] | None:
    r = doc.get("ramp")
    return None if r is None else {"pi": [float(x) for x in r["p_pi"]], "vf": [float(x) for x in r["p_vf"]]}


def _across_drop(doc: dict) -> AcrossDrop | None:
    h = doc.get("hand_over")
    if h is None:
        return None
    return AcrossDrop(int(h["drop"]), float(h["p_pi"]), float(h["p_vf"]), float(h["before"]), float(h["after"]))


def window_mean(run: Run, low: int, high: int) -> float:
    """CAT's estimator on one run: the mean of the per-iteration return of the episodes that finished in that
    iteration, over the iterations logged between `low` and `high` steps (iterations where none finished
    have no such return and are skipped, as CAT's logs have none). NaN where the window holds none."""
    return _window_mean(run.read_metrics(), low, high)


def _window_mean(rows: list[dict], low: int, high: int) -> float:
    """window_mean over rows already read."""
    values = [row["episode_return_iter"] for row in rows
              if low <= row["steps"] <= high and row.get("episode_return_iter") is not None]
    finite = [v for v in values if np.isfinite(v)]
    return float(np.mean(finite)) if finite else float("nan")


def at_step(m: MethodSummary, step: int) -> float:
    """The seed-mean curve at the last iteration at or before `step` (NaN before the first)."""
    i = int(np.searchsorted(m.steps, step, side="right")) - 1
    return float(m.mean[i]) if i >= 0 else float("nan")


def method_of(summary: StudySummary, pair_name: str, method: str) -> MethodSummary:
    pair = next(p for p in summary.pairs if p.name == pair_name)
    return next(m for m in pair.methods if m.name == method)


def _fmt(value: float) -> str:
    return "—" if not np.isfinite(value) else f"{value:,.0f}"


def _pm(values: list[float]) -> str:
    finite = [v for v in values if np.isfinite(v)]
    return mean_pm_std(np.array(finite)) if finite else "—"


def _window_label(window: tuple[int, int]) -> str:
    return f"{window[0] / 1e6:g}–{window[1] / 1e6:g}M"


def cat_lines(grid: Grid, summary: StudySummary, cat: Cat, method: str,
              fall: tuple[int, int] = FALL) -> list[str]:
    marks = [m for m in grid.marks if m <= grid.steps]
    head = ["teachers → target", "n", *(f"{who} {_window_label(w)}" for w in cat.windows for who in ("ours", "CAT"))]
    windows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    end = ["| teachers → target | n | " + " | ".join(f"ours at {m / 1e6:g}M" for m in marks)
           + f" | CAT {_window_label(cat.windows[-1])} | ours − CAT at {grid.steps / 1e6:g}M | reaches CAT | "
           f"mean curve {fall[0] / 1e6:g}M → {fall[1] / 1e6:g}M (lowest between) |",
           "|" + "---|" * (len(marks) + 6)]
    reached, compared, falls = 0, 0, 0
    for pair in grid.pairs:
        m = method_of(summary, pair.name, method)
        ref = cat.run_for(teachers_of(pair), pair.to)
        cat_cells = [_fmt(x) for x in ref.returns] if ref else ["—"] * len(cat.windows)
        ours = [_pm([window_mean(r, lo, hi) for r in m.runs]) for lo, hi in cat.windows]
        windows.append(f"| {pair.name} | {m.n} | "
                       + " | ".join(c for pair_cells in zip(ours, cat_cells, strict=True) for c in pair_cells) + " |")
        if not m.runs:
            end.append(f"| {pair.name} | 0 | " + " | ".join(["—"] * len(marks) + [cat_cells[-1], "—", "—", "—"])
                       + " |")
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
        start, stop = at_step(m, fall[0]), at_step(m, fall[1])
        between = m.mean[(m.steps >= fall[0]) & (m.steps <= fall[1])]
        fell = stop < start
        falls += fell
        trend = (f"{_fmt(start)} → {_fmt(stop)} ({'falls' if fell else 'no fall'}; "
                 f"{_fmt(float(np.min(between))) if between.size else '—'})")
        end.append(f"| {pair.name} | {m.n} | " + " | ".join(at_marks) + f" | {cat_cells[-1]} | {gap} | {verdict} | "
                   f"{trend} |")
    done = [p for p in grid.pairs if method_of(summary, p.name, method).n]
    full = all(method_of(summary, p.name, method).n == len(grid.seeds) for p in grid.pairs)
    return [
        "## Against CAT, pair by pair", "",
        f"`{method}` of `{grid.name}`, completed seeds only (n of the grid's {len(grid.seeds)}). CAT: 1 seed per "
        f"run, {cat.estimator}.", "",
        "**CAT's estimator.** Ours: each run's `episode_return_iter` (the mean return of the episodes that "
        "finished in that 2,048-step rollout, which is CAT's `eprewmean`) averaged over the iterations in the "
        "window, then mean ± sample std (ddof 1) over seeds.", "", *windows, "",
        "**The study's estimator, and the issue's test.** Ours: the mean training return over the last 100 "
        "episodes at each mark (the last iteration at or before it), mean ± sample std over seeds. \"Reaches "
        f"CAT\": the seed mean at {grid.steps / 1e6:g}M is at least CAT's {_window_label(cat.windows[-1])} "
        f"figure. The last column is the seed-mean curve at {fall[0] / 1e6:g}M and {fall[1] / 1e6:g}M and its "
        "lowest value between them.", "", *end, "",
        f"Reaches CAT on **{reached} of {compared}** pairs with completed seeds ({len(done)} of {len(grid.pairs)} "
        f"pairs have any); the mean curve falls between {fall[0] / 1e6:g}M and {fall[1] / 1e6:g}M on {falls}. "
        + ("Every pair has all its seeds." if full else
           "Not every pair has all the grid's seeds yet: these are partial results."), ""]


@dataclass(frozen=True)
class HandOver:
    """One run at the teacher drop: the last iteration with the teachers, and what follows it."""

    step: int
    lowest_weight: float  # the smallest student weight p over the layers of policy and value
    at_drop: float  # the study's estimator (the last 100 episodes) at that iteration
    lowest_after: float
    at_end: float


def _last_coupled(rows: list[dict]) -> int | None:
    """The index of the last iteration that trained with the teachers (None: never, or never dropped them)."""
    coupled = [i for i, row in enumerate(rows) if row.get("teacher_active") == 1.0]
    return coupled[-1] if coupled and coupled[-1] < len(rows) - 1 else None


def hand_over(run: Run) -> HandOver | None:
    """Where the run drops its teachers (None: it never trained with them, or never dropped them)."""
    rows = run.read_metrics()
    if (i := _last_coupled(rows)) is None:
        return None
    last, after = rows[i], rows[i + 1:]
    weights = [v for k, v in last.items() if k.startswith(("p_pi_", "p_vf_")) and v is not None]
    returns = [row["return_mean"] for row in after if row.get("return_mean") is not None]
    if not weights or not returns or last.get("return_mean") is None:
        return None
    return HandOver(last["steps"], min(weights), last["return_mean"], min(returns), returns[-1])


def hand_over_lines(grid: Grid, summary: StudySummary, method: str) -> list[str]:
    lines = ["## The hand-over at the teacher drop", "",
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
        steps = sorted({h.step for h, _ in found})
        drop = ", ".join(f"{s:,}" for s in steps)
        lines.append(f"| {pair.name} | {len(found)} | {drop} | "
                     f"{_pm2([h.lowest_weight for h, _ in found])} | {_pm([h.at_drop for h, _ in found])} | "
                     f"{_pm([h.lowest_after for h, _ in found])} | {_pm([h.at_end for h, _ in found])} | "
                     f"{_pm([float(e) for _, e in found])} |")
    return [*lines, ""]


def across_drop(run: Run, before: int) -> AcrossDrop | None:
    """Our run measured like CAT's logs at the drop (see AcrossDrop); None where it never dropped its teachers."""
    rows = run.read_metrics()
    if (i := _last_coupled(rows)) is None:
        return None
    drop = rows[i]["steps"]
    return AcrossDrop(drop, _branch_mean(rows[i], "pi"), _branch_mean(rows[i], "vf"),
                      _window_mean(rows, drop - before + 1, drop), _window_mean(rows, drop + 1, rows[-1]["steps"]))


def _branch_mean(row: dict, branch: str) -> float:
    """One branch's ("pi", "vf") student weight in a metrics row, averaged over its layers as CAT logs it."""
    weights = [v for k, v in row.items() if k.startswith(f"p_{branch}_") and v is not None]
    return float(np.mean(weights)) if weights else float("nan")


def across_drop_lines(grid: Grid, summary: StudySummary, cat: Cat, method: str) -> list[str]:
    """Ours beside CAT at the drop, with the measures CAT's logs have."""
    if cat.hand_over_before is None:
        return []
    before = cat.hand_over_before
    lines = ["**Across the drop, as CAT's logs measure it.** The student weight p at the last update with the "
             "teachers, averaged over the hidden layers of the policy (π) and of the value function (V): CAT logs "
             "that mean (`student_ps`, `vf_student_ps`). The return: the mean per-update return (`eprewmean`, "
             f"our `episode_return_iter`) over the {before:,} steps up to the drop and over every update after it; "
             "the change is after − before per run. Ours: mean ± sample std over seeds; CAT: 1 seed.", "",
             "| teachers → target | n | ours p π / V | CAT p π / V | ours before → after | ours change | "
             "runs that fall | CAT before → after | CAT change |", "|---|---|---|---|---|---|---|---|---|"]
    for pair in grid.pairs:
        m = method_of(summary, pair.name, method)
        ours = [h for h in (across_drop(r, before) for r in m.runs) if h is not None]
        ref = cat.run_for(teachers_of(pair), pair.to)
        c = ref.hand_over if ref else None
        cat_cells = ([f"{c.p_pi:.2f} / {c.p_vf:.2f}", f"{_fmt(c.before)} → {_fmt(c.after)}",
                      f"{c.after - c.before:+,.0f}"] if c else ["—"] * 3)
        if ours:
            change = [h.after - h.before for h in ours]
            our_cells = [f"{_pm2([h.p_pi for h in ours])} / {_pm2([h.p_vf for h in ours])}",
                         f"{_pm([h.before for h in ours])} → {_pm([h.after for h in ours])}",
                         _signed_pm(change), f"{sum(d < 0 for d in change)} of {len(change)}"]
        else:
            our_cells = ["—"] * 4
        lines.append(f"| {pair.name} | {len(ours)} | {our_cells[0]} | {cat_cells[0]} | {our_cells[1]} | "
                     f"{our_cells[2]} | {our_cells[3]} | {cat_cells[1]} | {cat_cells[2]} |")
    return [*lines, ""]


def branch_weight_at(rows: list[dict], step: int, branch: str) -> float:
    """The student weight of one branch ("pi", "vf"), averaged over its layers as CAT logs it, at the last
    iteration at or before `step` (NaN before the first, or where that row logs none)."""
    before = [row for row in rows if row["steps"] <= step]
    return _branch_mean(before[-1], branch) if before else float("nan")


def ramp_lines(grid: Grid, summary: StudySummary, cat: Cat, method: str) -> list[str]:
    """Ours beside CAT: each branch's student weight at marks inside the coupling ramp."""
    if not cat.ramp_marks:
        return []
    marks = cat.ramp_marks
    head = ["teachers → target", "branch", "n",
            *(f"{who} {m / 1e6:g}M" for m in marks for who in ("ours", "CAT"))]
    lines = ["## The student weights during the ramp", "",
             "The student weight p of each branch (π: policy, V: value function), averaged over its hidden layers "
             "as CAT logs it, at the last iteration at or before each mark; ours mean ± sample std over seeds, "
             "CAT 1 seed. 1 is the teachers unused: the coupling loss pushes p towards it.", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for pair in grid.pairs:
        m = method_of(summary, pair.name, method)
        ref = cat.run_for(teachers_of(pair), pair.to)
        rows = [r.read_metrics() for r in m.runs]
        for branch, label in (("pi", "π"), ("vf", "V")):
            ours = [_pm2(v) if (v := [x for x in (branch_weight_at(r, s, branch) for r in rows) if np.isfinite(x)])
                    else "—" for s in marks]
            theirs = [f"{x:.2f}" for x in ref.ramp[branch]] if ref and ref.ramp else ["—"] * len(marks)
            lines.append(f"| {pair.name} | {label} | {len(rows)} | "
                         + " | ".join(c for cells in zip(ours, theirs, strict=True) for c in cells) + " |")
    return [*lines, ""]


def _mean_sd(values: list[float], mean_format: str, sd_format: str | None = None) -> str:
    """mean ± sample std in the given formats; one value alone."""
    if len(values) == 1:
        return format(values[0], mean_format)
    return f"{format(np.mean(values), mean_format)} ± {format(np.std(values, ddof=1), sd_format or mean_format)}"


def _signed_pm(values: list[float]) -> str:
    """Changes, signed, in whole units."""
    return _mean_sd(values, "+,.0f", ",.0f")


def _pm2(values: list[float]) -> str:
    """Weights, with two decimals."""
    return _mean_sd(values, ".2f")


@dataclass(frozen=True)
class Family:
    """One curve of the across-studies section: a method of a study, on some of its pairs."""

    label: str
    summary: StudySummary
    method: str
    pairs: list[str]
    target_of: dict[str, str]


def scales(random: dict[str, float], baseline: MethodSummary | None, target: str) -> dict[str, tuple[float, float]]:
    """measure → (R_random, R_reference) on one target; empty where the baseline has no run or no scale."""
    if baseline is None or not baseline.runs or target not in random:
        return {}
    out = {}
    for measure in MEASURES:
        values = baseline.per_seed[measure]
        ref = float(np.mean(values[np.isfinite(values)])) if np.isfinite(values).any() else float("nan")
        if np.isfinite(ref) and ref > random[target]:
            out[measure] = (random[target], ref)
    return out


def family_scores(family: Family, measure: str, scale: dict[str, dict[str, tuple[float, float]]],
                  by: str) -> Scores:
    """The family's normalised runs, grouped by pair or by target (`by`)."""
    scores: dict[str, list[np.ndarray]] = {}
    for pair in family.pairs:
        target = family.target_of[pair]
        m = method_of(family.summary, pair, family.method)
        values = m.per_seed[measure] if m.runs else np.zeros(0)
        values = values[np.isfinite(values)]
        if not values.size or measure not in scale.get(target, {}):
            continue
        scores.setdefault(pair if by == "pair" else target, []).append(
            across_tasks.normalized(values, *scale[target][measure]))
    return {key: np.concatenate(parts) for key, parts in scores.items()}


def _estimate(e: across_tasks.Estimate) -> str:
    return f"{e.value:.2f} [{e.low:.2f}, {e.high:.2f}]"


def across_lines(families: list[Family], baseline_of: dict[str, MethodSummary | None], random: dict[str, float],
                 random_source: str, n_resamples: int, profile: Path) -> list[str]:
    targets = list(dict.fromkeys(t for f in families for t in f.target_of.values()))
    scale = {t: scales(random, baseline_of.get(t), t) for t in targets}
    lines = ["## Across studies: two teachers, one teacher, none", "",
             "Each run's score is normalised on its target, `(R − R_random) / (R_ppo − R_random)`: 0 is the "
             f"random policy (`{random_source}`), 1 the mean of PPO from scratch on that target at the same budget. "
             "The IQM (25 % trimmed mean over all runs × pairs pooled) and the mean come with 95 % percentile "
             "stratified bootstrap intervals (runs resampled within each pair; "
             f"{n_resamples:,} resamples, seed {SEED}). The one-teacher pairs are other tasks than the two-teacher "
             "pairs, so P(X > Y), the chance that a run of X beats a run of Y on the same target (Mann–Whitney "
             "U / (n_x n_y)), is taken per target body, pooling a family's pairs on it, and averaged over the "
             "targets both families have.", "",
             "| target | R_random | PPO: final return | PPO: mean over training | PPO runs |", "|---|---|---|---|---|"]
    for t in targets:
        base = baseline_of.get(t)
        refs = [_fmt(scale[t][m][1]) if m in scale[t] else "—" for m in MEASURES]
        lines.append(f"| {t} | {random[t]:,.1f} | " if t in random else f"| {t} | — | ")
        lines[-1] += " | ".join(refs) + f" | {base.n if base else 0} |"
    lines.append("")
    profiles = {}
    for measure in MEASURES:
        by_pair = {f.label: family_scores(f, measure, scale, "pair") for f in families}
        by_target = {f.label: family_scores(f, measure, scale, "target") for f in families}
        lines += [f"### {measure[0].upper() + measure[1:]}", "",
                  "| family | runs | pairs | targets | IQM [95 % CI] | mean [95 % CI] |", "|---|---|---|---|---|---|"]
        for f in families:
            scores = by_pair[f.label]
            if not scores:
                lines.append(f"| {f.label} | 0 | 0 | — | — | — |")
                continue
            runs = sum(v.size for v in scores.values())
            lines.append(f"| {f.label} | {runs} | {len(scores)} | {', '.join(by_target[f.label])} | "
                         f"{_estimate(across_tasks.iqm_estimate(scores, n_resamples, SEED))} | "
                         f"{_estimate(across_tasks.mean_estimate(scores, n_resamples, SEED))} |")
        lines += ["", "| X vs Y | P(X > Y) [95 % CI] | targets |", "|---|---|---|"]
        for i, x in enumerate(families):
            for y in families[i + 1:]:
                shared = [t for t in by_target[x.label] if t in by_target[y.label]]
                if not shared:
                    lines.append(f"| {x.label} vs {y.label} | — (no shared target) | 0 |")
                    continue
                e = across_tasks.probability_of_improvement_estimate(by_target[x.label], by_target[y.label],
                                                                  n_resamples, SEED)
                lines.append(f"| {x.label} vs {y.label} | {_estimate(e)} | {', '.join(shared)} |")
        lines.append("")
        if measure == MEASURES[0]:
            profiles = {label: s for label, s in by_pair.items() if s}
    if profiles:
        top = max(float(np.max(np.concatenate(list(s.values())))) for s in profiles.values())
        taus = np.linspace(0.0, max(top, 1.0) * 1.05, PROFILE_POINTS)
        drawn = {}
        for label, scores in profiles.items():
            point, low, high = across_tasks.performance_profile_estimate(scores, taus, PROFILE_RESAMPLES, SEED)
            drawn[label] = (taus.tolist(), point.tolist(), low.tolist(), high.tolist())
        png_performance_profiles(drawn, profile,
                                 f"performance profiles ({MEASURES[0]}, normalised; 95 % bands)",
                                 order=[f.label for f in families])  # each family keeps its colour as runs arrive
        lines += [f"![performance profiles]({profile.name})", ""]
    return lines


def report(study: Path, grid: Grid, one_study: Path, one_grid: Grid, cat: Cat, random: dict[str, float],
           random_source: str, method: str = "mikt", n_resamples: int = across_tasks.RESAMPLES,
           fall: tuple[int, int] = FALL, out: Path | None = None) -> Path:
    """The report, every family on the two-teacher grid's seeds (so every figure averages the same seeds), at
    `out` (default STUDY/against-cat.md; its figure beside it, named after it). The across-studies section needs
    the grid's baseline to be PPO from scratch; a screening whose baseline is another transfer has none."""
    path = out or study / "against-cat.md"
    summary = summarise(grid, json.loads((study / "state.json").read_text()), snapshot_runs(study))
    against_cat = [*cat_lines(grid, summary, cat, method, fall), *ramp_lines(grid, summary, cat, method),
                   *hand_over_lines(grid, summary, method), *across_drop_lines(grid, summary, cat, method)]
    if next(m for m in grid.methods if m.name == grid.baseline).uses_teachers:
        lines = [f"# {grid.name}: `{method}` against CAT", "",
                 f"Made by `benchmarks/multi_teacher_report.py` from the snapshots of `{grid.name}`, seeds "
                 f"{grid.seeds}. No comparison across studies: this grid's baseline, `{grid.baseline}`, is not PPO "
                 "from scratch.", "", *against_cat]
        left_out = summary.left_out
    else:
        one_grid = one_grid.model_copy(update={"seeds": grid.seeds})
        one = summarise(one_grid, json.loads((one_study / "state.json").read_text()), snapshot_runs(one_study))
        one_pairs = [p for p in one_grid.pairs
                     if p.to in {q.to for q in grid.pairs} and len(p.teachers) == 1]
        lines = [f"# {grid.name}: two-teacher MIKT against CAT, one-teacher MIKT and PPO from scratch", "",
                 f"Made by `benchmarks/multi_teacher_report.py` from the snapshots of `{grid.name}` and "
                 f"`{one_grid.name}` (one-teacher pairs on the same targets: "
                 f"{', '.join(p.name for p in one_pairs) or 'none'}), seeds {grid.seeds} of both.", "",
                 *against_cat, *across_studies(grid, summary, one, one_pairs, method, random, random_source,
                                               n_resamples, path.with_name(f"{path.stem}-profile.png"))]
        left_out = summary.left_out + one.left_out
    if left_out:
        lines += ["Left out (files incomplete): " + "; ".join(left_out), ""]
    write_text_atomic(path, "\n".join(lines))
    return path


def across_studies(grid: Grid, summary: StudySummary, one: StudySummary, one_pairs: list[PairSpec], method: str,
                   random: dict[str, float], random_source: str, n_resamples: int, profile: Path) -> list[str]:
    """Two-teacher `method`, one-teacher `method` and the grid's baseline (PPO from scratch), across studies."""
    targets = list(dict.fromkeys(p.to for p in grid.pairs))
    baseline_of: dict[str, MethodSummary | None] = {}
    for pair in grid.pairs:  # PPO from scratch: its runs are the same for every pair of a target
        m = method_of(summary, pair.name, grid.baseline)
        if m.runs and pair.to not in baseline_of:
            baseline_of[pair.to] = m
    families = [
        Family(f"two-teacher {method}", summary, method, [p.name for p in grid.pairs],
               {p.name: p.to for p in grid.pairs}),
        Family(f"one-teacher {method}", one, method, [p.name for p in one_pairs], {p.name: p.to for p in one_pairs}),
        Family(f"{grid.baseline} (from scratch)", summary, grid.baseline,
               [next(p.name for p in grid.pairs if p.to == t) for t in targets], {p.name: p.to for p in grid.pairs}),
    ]
    return across_lines(families, baseline_of, random, random_source, n_resamples, profile)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("study", type=Path, help="the two-teacher study's results folder (state.json, runs/)")
    parser.add_argument("--grid", type=Path, help="its grid (default: benchmarks/grids/FOLDER-NAME.toml)")
    parser.add_argument("--one-teacher", type=Path, default=ROOT / "benchmarks" / "results" / "paper-2m" / "paper-2m",
                        help="the one-teacher study's results folder")
    parser.add_argument("--one-teacher-grid", type=Path, help="its grid (default: by its folder's name)")
    parser.add_argument("--cat", type=Path, default=ROOT / "benchmarks" / "reference" / "cat-uai2022.toml")
    parser.add_argument("--random", type=Path, default=ROOT / "benchmarks" / "results" / "random-policy.json")
    parser.add_argument("--method", default="mikt", help="the grid's two-teacher method to set against CAT")
    parser.add_argument("--out", type=Path, help="the report's file (default: STUDY/against-cat.md)")
    args = parser.parse_args()
    grids = ROOT / "benchmarks" / "grids"
    grid = load_grid(args.grid or grids / f"{args.study.name}.toml")
    one_grid = load_grid(args.one_teacher_grid or grids / f"{args.one_teacher.name}.toml")
    random = {t: v["return_mean"] for t, v in json.loads(args.random.read_text())["targets"].items()}
    source = args.random.resolve()  # named in the report: relative to the checkout, never this machine's path
    source = source.relative_to(ROOT) if source.is_relative_to(ROOT) else source
    print(report(args.study, grid, args.one_teacher, one_grid, load_cat(args.cat), random, str(source),
                 args.method, out=args.out))


if __name__ == "__main__":
    main()
