"""Aggregates across a study's pairs, after Agarwal et al. 2021 ("Deep RL at the Edge of the Statistical
Precipice"): normalised scores, the interquartile mean with 95 % stratified bootstrap intervals, the
probability of improvement and performance profiles.

    PYTHONPATH=src python benchmarks/aggregate_report.py benchmarks/results/paper-2m/paper-2m \\
        [--grid benchmarks/grids/paper-2m.toml] [--random benchmarks/results/random-policy.json]

Each completed run's score is normalised on its target between the uniform-random policy (random-policy.json,
made by benchmarks/random_returns.py) and the grid's baseline (PPO from scratch, `vpg`) at the same budget: the
mean of the baseline's completed runs on that target. Tasks are the grid's pairs; a method without teachers
(vpg) has the same runs on every pair of its target. Runs are read from the study's committed snapshots, so
this works from a fresh clone. Writes `STUDY/aggregate.md` and `STUDY/aggregate-profile.png`.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from cross_study import snapshot_runs

from miktcli import aggregate
from miktcli.plots import png_performance_profiles
from miktcli.registry.files import write_text_atomic
from miktcli.studies.grid import Grid, load_grid
from miktcli.studies.summary import completed_curves

ROOT = Path(__file__).resolve().parents[1]
MEASURES = {"final return": "the mean training return over the last 100 episodes at the end of the run",
            "mean over training": "that curve averaged over the whole run (area under the curve)"}
SEED = 0  # every interval of the report is reproducible from this seed


def raw_scores(grid: Grid, study: Path) -> tuple[dict[str, dict[str, dict[str, np.ndarray]]], list[str]]:
    """measure → method → pair → one raw value per completed run, and the runs left out (with why)."""
    run_of, left_out = snapshot_runs(study), []
    out: dict[str, dict[str, dict[str, np.ndarray]]] = {m: {} for m in MEASURES}
    for method in grid.methods:
        for pair in grid.pairs:
            runs, _, curves = completed_curves(grid, run_of, pair, method, left_out)
            if runs:
                out["final return"].setdefault(method.name, {})[pair.name] = curves[:, -1]
                out["mean over training"].setdefault(method.name, {})[pair.name] = np.nanmean(curves, axis=1)
    return out, left_out


def fmt(e: aggregate.Estimate) -> str:
    return f"{e.value:.2f} [{e.low:.2f}, {e.high:.2f}]"


def aggregate_report(study: Path, grid: Grid, random: dict[str, float], out_dir: Path | None = None,
                     n_resamples: int = aggregate.RESAMPLES) -> Path:
    out_dir = out_dir or study
    raw, left_out = raw_scores(grid, study)
    base = grid.baseline
    targets = sorted({p.to for p in grid.pairs})
    missing = [t for t in targets if t not in random]
    if missing:
        raise SystemExit(f"Error: no random-policy return for {', '.join(missing)}; run benchmarks/random_returns.py")
    pair_target = {p.name: p.to for p in grid.pairs}
    lines = [f"# {grid.name}: aggregates across pairs", "",
             f"Each completed run's score is normalised on its target, `(R − R_random) / (R_{base} − R_random)`: "
             f"0 is the uniform-random policy, 1 is `{base}` (PPO from scratch) at the same budget "
             f"({grid.steps:,} steps), R_{base} the mean of its completed runs on that target. Tasks are the "
             f"{len(grid.pairs)} pairs; `{base}` has the same runs on every pair of its target. IQM: the 25 % "
             "trimmed mean over all runs × pairs pooled; intervals: 95 % percentile stratified bootstrap (each "
             f"pair's runs resampled within the pair; {n_resamples:,} resamples, seed {SEED}); probability of "
             "improvement: per pair the Mann–Whitney U / (n_x n_y), averaged over pairs (Agarwal et al. 2021). "
             "Made by `benchmarks/aggregate_report.py` (scipy; random returns: benchmarks/results/"
             "random-policy.json).", ""]
    normalised: dict[str, dict[str, dict[str, np.ndarray]]] = {}
    for measure, methods in raw.items():
        if base not in methods:
            raise SystemExit(f"Error: {study}: no completed {base} run to normalise by")
        reference = {}
        for target in targets:
            runs = [v for pair, v in methods[base].items() if pair_target[pair] == target]
            if runs:  # the baseline's runs on a target are one set, whichever pair names them
                reference[target] = float(np.mean(runs[0]))
        normalised[measure] = {
            m: {pair: aggregate.normalized(v, random[pair_target[pair]], reference[pair_target[pair]])
                for pair, v in by_pair.items() if pair_target[pair] in reference}
            for m, by_pair in methods.items()}
        if measure == "final return":
            lines += ["## Normalisation", "", f"| target | R_random | R_{base} ({measure}) | n |", "|---|---|---|---|"]
            for target in targets:
                n = next((len(v) for p, v in methods[base].items() if pair_target[p] == target), 0)
                ref = f"{reference[target]:,.0f}" if target in reference else "—"
                lines.append(f"| {target} | {random[target]:,.1f} | {ref} | {n} |")
            lines.append("")
    for measure, methods in normalised.items():
        lines += [f"## {measure[0].upper()}{measure[1:]}", "",
                  f"Score: {MEASURES[measure]}, normalised by the same measure of `{base}`.", "",
                  "| method | runs | pairs | IQM [95 % CI] | mean [95 % CI] |", "|---|---|---|---|---|"]
        for name, by_pair in methods.items():
            est = aggregate.iqm_estimate(by_pair, n_resamples=n_resamples, seed=SEED)
            mean = aggregate.mean_estimate(by_pair, n_resamples=n_resamples, seed=SEED)
            runs = sum(len(v) for v in by_pair.values())
            lines.append(f"| {name} | {runs} | {len(by_pair)} | {fmt(est)} | {fmt(mean)} |")
        lines += ["", "| X vs Y | P(X > Y) [95 % CI] | pairs |", "|---|---|---|"]
        names = list(methods)
        for i, x in enumerate(names):
            for y in names[i + 1:]:
                shared = [p for p in methods[x] if p in methods[y]]
                if shared:
                    poi = aggregate.probability_of_improvement_estimate(methods[x], methods[y],
                                                                        n_resamples=n_resamples, seed=SEED)
                    lines.append(f"| {x} vs {y} | {fmt(poi)} | {len(shared)} |")
        lines += ["", "Per pair (IQM of its runs, normalised):", "",
                  "| pair | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
        for pair in grid.pairs:
            cells = [f"{aggregate.iqm({pair.name: methods[m][pair.name]}):.2f}" if pair.name in methods[m] else "—"
                     for m in names]
            lines.append(f"| {pair.name} | " + " | ".join(cells) + " |")
        lines.append("")
    final = normalised["final return"]
    top = max(float(np.max(np.concatenate(list(v.values())))) for v in final.values())
    taus = np.linspace(0.0, max(top, 1.0) * 1.05, 101)
    profiles = {}
    for name, by_pair in final.items():
        point, low, high = aggregate.performance_profile_estimate(by_pair, taus, n_resamples=2_000, seed=SEED)
        profiles[name] = (taus.tolist(), point.tolist(), low.tolist(), high.tolist())
    png = png_performance_profiles(profiles, out_dir / "aggregate-profile.png",
                                   f"{grid.name}: performance profiles (final return, normalised; 95 % bands)")
    lines += ["## Performance profiles", "", f"![performance profiles]({png.name})", "",
              "The fraction of runs whose normalised final return is above τ, averaged over pairs, with pointwise "
              "95 % stratified bootstrap bands (2,000 resamples).", ""]
    if left_out:
        lines += ["Left out (files incomplete): " + "; ".join(left_out), ""]
    path = out_dir / "aggregate.md"
    write_text_atomic(path, "\n".join(lines))
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("study", type=Path, help="a study's results folder (state.json, runs/)")
    parser.add_argument("--grid", type=Path, help="its grid (default: benchmarks/grids/FOLDER-NAME.toml)")
    parser.add_argument("--random", type=Path, default=ROOT / "benchmarks" / "results" / "random-policy.json")
    args = parser.parse_args()
    grid = load_grid(args.grid or ROOT / "benchmarks" / "grids" / f"{args.study.name}.toml")
    random = {t: v["return_mean"] for t, v in json.loads(args.random.read_text())["targets"].items()}
    try:
        print(aggregate_report(args.study, grid, random))
    except ValueError as err:  # a baseline no better than random on some target: no scale to normalise on
        raise SystemExit(f"Error: {err}") from None


if __name__ == "__main__":
    main()
