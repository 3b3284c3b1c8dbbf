"""The teacher-similarity figures (the paper's Figures 5 and 6): MIKT on one target taught by different teachers,
next to PPO from scratch, from the finished runs of two studies.

    python benchmarks/similarity_report.py benchmarks/results/paper-2m [--main paper-2m]
        [--similarity paper-2m-similarity]

The similarity grid names the target and the extra teacher (hopper → centipede-eight); the main grid holds the
other teachers of that target (centipede-four, centipede-six) and the baseline (vpg). Every curve uses the
similarity grid's seeds, so all curves average the same seeds. Runs are read from the committed snapshots
(`STUDY/runs/RUN/`, written by benchmarks/snapshot_study.py), so this works from a fresh clone. Writes
`SIMILARITY/similarity.md`, `similarity-curves.png` and `similarity-weights.png`.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from miktcli.plots import png_plot
from miktcli.registry.cards import RunCard
from miktcli.registry.files import write_text_atomic
from miktcli.registry.runs import Run
from miktcli.workflows.grid import Grid, MethodSpec, PairSpec, load_grid
from miktcli.workflows.report import completed_curves, mean_pm_std, sample_std

ROOT = Path(__file__).resolve().parents[1]


def snapshot_runs(results: Path):
    """A cell key → its run, read from the study's snapshot folder (None when not finished and copied)."""
    state = json.loads((results / "state.json").read_text()) if (results / "state.json").exists() else {}

    def run_of(key: str) -> Run | None:
        folder = results / "runs" / state.get(key, "-")
        if not (folder / "run.json").is_file():
            return None
        return Run(folder, RunCard.model_validate_json((folder / "run.json").read_text()))

    return run_of


def teachers_of(pair: PairSpec) -> str:
    return "+".join(t.split("@")[0] for t in pair.teachers)


def method_named(grid: Grid, name: str) -> MethodSpec:
    for method in grid.methods:
        if method.name == name:
            return method
    raise SystemExit(f"grid '{grid.name}' has no method '{name}'")


def similarity_report(root: Path, main_name: str, similarity_name: str, method_name: str = "mikt",
                      grids: Path = ROOT / "benchmarks" / "grids") -> Path:
    main, similar = (load_grid(grids / f"{n}.toml") for n in (main_name, similarity_name))
    targets = {p.to for p in similar.pairs}
    if len(targets) != 1:
        raise SystemExit(f"grid '{similar.name}' must have one target, has {sorted(targets)}")
    target = targets.pop()
    seeds = similar.seeds
    main_runs, similar_runs = snapshot_runs(root / main_name), snapshot_runs(root / similarity_name)
    groups: list[tuple[str, Grid, object, PairSpec, MethodSpec]] = [
        *((f"{method_name} ← {teachers_of(p)}", main, main_runs, p, method_named(main, method_name))
          for p in main.pairs if p.to == target),
        *((f"{method_name} ← {teachers_of(p)}", similar, similar_runs, p, method_named(similar, method_name))
          for p in similar.pairs),
    ]
    labels = [label for label, *_ in groups]
    if len(set(labels)) != len(labels):
        raise SystemExit(f"the same teachers of {target} are in both grids: {sorted(labels)}")
    baseline_pair = next((p for p in main.pairs if p.to == target), None)
    if baseline_pair is not None:
        groups.append((main.baseline, main, main_runs, baseline_pair, method_named(main, main.baseline)))

    marks = [m for m in similar.marks if m <= similar.steps] or [similar.steps]
    header = ["curve", "n", *(f"{m:,}" for m in marks), "mean over training", "final eval (no teacher)",
              "final p (π / V)"]
    lines = [f"# Teacher similarity on {target}", "",
             f"MIKT ({method_name}) on {target} taught by each teacher, and {main.baseline} (from scratch); seeds "
             f"{seeds} for every curve, {similar.steps:,} steps. Mean training return over the last 100 episodes at "
             "each mark (the last iteration at or before it), mean ± sample std (ddof 1) over the n finished seeds. "
             f"Runs from `{main_name}` and `{similarity_name}` (see their results.md for the run ids).", "",
             "![curves](similarity-curves.png)", "", "![student weights](similarity-weights.png)", "",
             "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    series, bands, weights = {}, {}, {}
    left_out: list[str] = []
    for label, grid, run_of, pair, method in groups:
        runs, steps, curves = completed_curves(grid.model_copy(update={"seeds": seeds}), run_of, pair, method,
                                               left_out)
        if not runs:
            lines.append(f"| {label} | 0 | " + " | ".join("—" for _ in header[2:]) + " |")
            continue
        mean, std = np.nanmean(curves, 0), np.nan_to_num(sample_std(curves, axis=0))
        at = [int(np.searchsorted(steps, m, side="right")) - 1 for m in marks]
        cells = ["—" if i < 0 else mean_pm_std(curves[:, i]) for i in at]
        evals = [r.card.result["eval_without_teacher"]["return_mean"] for r in runs]
        mixing = [r.card.result.get("final_mixing_learned") or {} for r in runs]
        p = "—"
        if all(m.get("p_pi_0") is not None for m in mixing):
            p = (f"{np.mean([m['p_pi_0'] for m in mixing]):.2f} / {np.mean([m['p_vf_0'] for m in mixing]):.2f}")
            # averaged at the steps every run logged (a damaged metrics line drops a step, never shifts one)
            by_step = [{row["steps"]: row.get("p_pi_0") for row in r.read_metrics()} for r in runs]
            common = sorted(set.intersection(*(set(b) for b in by_step)))
            weights[f"{label} (π)"] = [(step, float(np.mean([b[step] for b in by_step]))) for step in common
                                      if all(b[step] is not None for b in by_step)]
        lines.append(f"| {label} | {len(runs)} | " + " | ".join(cells)
                     + f" | {mean_pm_std(np.nanmean(curves, axis=1))} | {mean_pm_std(evals)} | {p} |")
        series[label] = list(zip(steps.tolist(), mean.tolist(), strict=True))
        bands[label] = list(zip(steps.tolist(), (mean - std).tolist(), (mean + std).tolist(), strict=True))
    out = root / similarity_name
    out.mkdir(parents=True, exist_ok=True)
    if series:
        png_plot(series, out / "similarity-curves.png", f"teachers of {target}", "mean episode return", bands)
    if weights:
        png_plot(weights, out / "similarity-weights.png", f"{target}: student weight p (policy)", "p (student)")
    if left_out:
        lines += ["", "Completed runs left out (incomplete files):", "", *(f"- {problem}" for problem in left_out)]
    lines.append("")
    lines.append("p is the weight on the student's own representation in the weighted combination with the "
                 "teacher's (1 = the teacher unused). The paper (Section 5, Figure 5): the centipede teachers help "
                 "far more than Hopper, and with Hopper p rises sharply early in training.")
    path = out / "similarity.md"
    write_text_atomic(path, "\n".join(lines) + "\n")
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root", type=Path, help="the folder holding both studies' result folders")
    parser.add_argument("--main", default="paper-2m")
    parser.add_argument("--similarity", default="paper-2m-similarity")
    parser.add_argument("--method", default="mikt")
    args = parser.parse_args()
    print(similarity_report(args.root, args.main, args.similarity, args.method))


if __name__ == "__main__":
    main()
