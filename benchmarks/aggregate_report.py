"""Aggregates across a study's pairs, after Agarwal et al. 2021 ("Deep RL at the Edge of the Statistical
Precipice"): normalised scores, the interquartile mean with 95 % stratified bootstrap intervals, the
probability of improvement and performance profiles.

    PYTHONPATH=src python benchmarks/aggregate_report.py benchmarks/results/paper-2m/paper-2m \\
        [--grid benchmarks/grids/paper-2m.toml] [--random benchmarks/results/random-policy.json]

Every study report (`mikt study`, `--report-only`) carries the same section ("Across pairs" in results.md,
`across_pairs` in summary.json; the library's studies.aggregates), with the random returns of the study
folder's random-returns.json. This script makes it from a study's committed snapshots with another file of
random-policy returns (default: benchmarks/results/random-policy.json, made by benchmarks/random_returns.py),
so it works from a fresh clone and writes nothing into the registry. Writes `STUDY/across_tasks.md` and
`STUDY/aggregate-profile.png`.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from miktcli.registry.files import write_text_atomic
from miktcli.stats import across_tasks
from miktcli.studies.across_studies import snapshot_runs
from miktcli.studies.aggregates import across_pairs
from miktcli.studies.grid import Grid, load_grid
from miktcli.studies.render_figures import write_profiles
from miktcli.studies.render_markdown import across_pairs_lines
from miktcli.studies.summary import summarise

ROOT = Path(__file__).resolve().parents[1]


def aggregate_report(study: Path, grid: Grid, random: dict[str, float], out_dir: Path | None = None,
                     n_resamples: int = across_tasks.RESAMPLES,
                     random_source: str = "benchmarks/results/random-policy.json") -> Path:
    out_dir = out_dir or study
    missing = sorted({p.to for p in grid.pairs} - set(random))
    if missing:
        raise SystemExit(f"Error: no random-policy return for {', '.join(missing)}; run benchmarks/random_returns.py")
    state = json.loads((study / "state.json").read_text())
    summary = summarise(grid, state, snapshot_runs(study))
    section = across_pairs(summary, random, random_source, n_resamples=n_resamples)
    write_profiles(section, out_dir, grid.name)
    lines = [f"# {grid.name}: aggregates across pairs", "",
             "Made by `benchmarks/aggregate_report.py` from the study's snapshots; its results.md carries the same "
             "section.", "", *across_pairs_lines(section)]
    if summary.left_out:
        lines += ["Left out (files incomplete): " + "; ".join(summary.left_out), ""]
    path = out_dir / "across_tasks.md"
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
    source = args.random.resolve()  # named in the report: relative to the checkout, never this machine's path
    source = source.relative_to(ROOT) if source.is_relative_to(ROOT) else source
    print(aggregate_report(args.study, grid, random, random_source=str(source)))


if __name__ == "__main__":
    main()
