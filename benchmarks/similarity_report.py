"""The teacher-similarity figures (the paper's Figures 5 and 6): MIKT on one target taught by different teachers,
next to PPO from scratch, from the finished runs of two studies.

    python benchmarks/similarity_report.py benchmarks/results/paper-2m [--main paper-2m]
        [--similarity paper-2m-similarity]

The similarity grid names the target and the extra teacher (hopper → centipede-eight); the main grid holds the
other teachers of that target (centipede-four, centipede-six) and the baseline (vpg). Every curve uses the
similarity grid's seeds, so all curves average the same seeds. Runs are read from the committed snapshots
(`STUDY/runs/RUN/`, written by benchmarks/snapshot_study.py), so this works from a fresh clone. Writes
`SIMILARITY/similarity.md` (the table and the over-seeds comparisons), `similarity-curves.png` and
`similarity-weights.png`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from miktcli.registry.files import write_text_atomic
from miktcli.stats.plots import png_plot
from miktcli.studies.across_studies import Group, curves_of, method_named, snapshot_runs, table_head
from miktcli.studies.grid import load_grid
from miktcli.studies.render_markdown import comparison_lines
from miktcli.studies.summary import compare_methods, partial_seed_labels

ROOT = Path(__file__).resolve().parents[1]


def similarity_report(root: Path, main_name: str, similarity_name: str, method_name: str = "mikt",
                      grids: Path = ROOT / "benchmarks" / "grids") -> Path:
    main, similar = (load_grid(grids / f"{n}.toml") for n in (main_name, similarity_name))
    targets = {p.to for p in similar.pairs}
    if len(targets) != 1:
        raise SystemExit(f"grid '{similar.name}' must have one target, has {sorted(targets)}")
    target = targets.pop()
    seeds = similar.seeds
    main_runs, similar_runs = snapshot_runs(root / main_name), snapshot_runs(root / similarity_name)
    groups = [
        *(Group(f"{method_name} ← {p.teacher_names}", main, main_runs, p, method_named(main, method_name))
          for p in main.pairs if p.to == target),
        *(Group(f"{method_name} ← {p.teacher_names}", similar, similar_runs, p, method_named(similar, method_name))
          for p in similar.pairs),
    ]
    labels = [g.label for g in groups]
    if len(set(labels)) != len(labels):
        raise SystemExit(f"the same teachers of {target} are in both grids: {sorted(labels)}")
    baseline_pair = next((p for p in main.pairs if p.to == target), None)
    if baseline_pair is not None:
        groups.append(Group(main.baseline, main, main_runs, baseline_pair, method_named(main, main.baseline)))

    marks = [m for m in similar.marks if m <= similar.steps] or [similar.steps]
    lines = [f"# Teacher similarity on {target}", "",
             f"MIKT ({method_name}) on {target} taught by each teacher, and {main.baseline} (from scratch); seeds "
             f"{seeds} for every curve, {similar.steps:,} steps. Mean training return over the last 100 episodes at "
             "each mark (the last iteration at or before it), mean ± sample std (ddof 1) over the n finished seeds. "
             f"Runs from `{main_name}` and `{similarity_name}` (see their results.md for the run ids).", "",
             "![curves](similarity-curves.png)", "", "![student weights](similarity-weights.png)", "",
             *table_head(marks)]
    found = curves_of(groups, seeds, marks)
    lines += found.rows
    # The same over-seeds test as the study and controls reports: which teacher differences the seeds can separate.
    compared = comparison_lines(compare_methods(found.per_seed))
    lines += compared
    series, bands, weights, left_out = found.series, found.bands, found.weights, found.left_out
    out = root / similarity_name
    out.mkdir(parents=True, exist_ok=True)
    if series:
        png_plot(series, out / "similarity-curves.png", f"teachers of {target}", "mean episode return", bands,
                 labels=partial_seed_labels(found.counts, len(seeds)))
    if weights:
        png_plot(weights, out / "similarity-weights.png", f"{target}: student weight p (policy)", "p (student)",
                 labels=partial_seed_labels(found.weight_counts, len(seeds)))
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
