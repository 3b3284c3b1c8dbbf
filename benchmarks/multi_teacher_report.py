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
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from miktcli.registry.files import write_text_atomic
from miktcli.stats import across_tasks
from miktcli.stats.plots import png_performance_profiles
from miktcli.studies.across_studies import snapshot_runs
from miktcli.studies.grid import Grid, PairSpec, load_grid
from miktcli.studies.reference import Reference, load_reference
from miktcli.studies.render_reference import method_of, reference_lines, whole
from miktcli.studies.summary import MethodSummary, StudySummary, summarise

ROOT = Path(__file__).resolve().parents[1]
MEASURES = ("final return", "mean over training")
FALL = (1_000_000, 1_500_000)  # the "no fall between 1M and 1.5M on the mean curve"
SEED = 0
PROFILE_POINTS = 101
PROFILE_RESAMPLES = 2_000

Scores = dict[str, np.ndarray]  # stratum (a pair or a target) → one normalised score per run


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
        refs = [whole(scale[t][m][1]) if m in scale[t] else "—" for m in MEASURES]
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


def report(study: Path, grid: Grid, one_study: Path, one_grid: Grid, cat: Reference, random: dict[str, float],
           random_source: str, method: str = "mikt", n_resamples: int = across_tasks.RESAMPLES,
           fall: tuple[int, int] = FALL, out: Path | None = None) -> Path:
    """The report, every family on the two-teacher grid's seeds (so every figure averages the same seeds), at
    `out` (default STUDY/against-cat.md; its figure beside it, named after it). The across-studies section needs
    the grid's baseline to be PPO from scratch; a screening whose baseline is another transfer has none."""
    path = out or study / "against-cat.md"
    summary = summarise(grid, json.loads((study / "state.json").read_text()), snapshot_runs(study))
    against_cat = reference_lines(grid, summary, cat, method, "CAT", fall)
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
    print(report(args.study, grid, args.one_teacher, one_grid, load_reference(args.cat), random, str(source),
                 args.method, out=args.out))


if __name__ == "__main__":
    main()
