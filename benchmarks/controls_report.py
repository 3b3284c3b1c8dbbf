"""The controls and ablations next to the runs they question: for each of their pairs, MIKT and PPO from scratch
from the main grid beside `vpg + KL` (is part of MIKT's gain just the KL regulariser?) and MIKT without the MI
loss or without RL gradients into the encoders, on the same seeds, with the over-seeds comparisons.

    python benchmarks/controls_report.py benchmarks/results/paper-2m [--main paper-2m]
        [--controls paper-2m-controls] [--ablations paper-2m-ablations]

Runs are read from each study's committed snapshots, so this works from a fresh clone and before every grid
has finished (a group with no finished run shows n = 0). Writes `ROOT/controls.md` and one
`controls-PAIR.png` per pair.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from miktcli.registry.files import write_text_atomic
from miktcli.stats.plots import png_plot
from miktcli.studies.across_studies import Group, curves_of, method_named, snapshot_runs, table_head
from miktcli.studies.grid import Grid, PairSpec, file_slug, load_grid
from miktcli.studies.render_markdown import comparison_lines
from miktcli.studies.summary import compare_methods, partial_seed_labels

ROOT = Path(__file__).resolve().parents[1]


def same_pair(a: PairSpec, b: PairSpec) -> bool:
    return a.teachers == b.teachers and a.to == b.to


def main_groups(main: Grid, main_runs, pair: PairSpec, method_name: str) -> list[Group]:
    """The main grid's mikt on this pair and its baseline on this target (shared by every pair of the target)."""
    groups = []
    mikt_pair = next((p for p in main.pairs if same_pair(p, pair)), None)
    if mikt_pair is not None:
        groups.append(Group(method_name, main, main_runs, mikt_pair, method_named(main, method_name)))
    base_pair = mikt_pair or next((p for p in main.pairs if p.to == pair.to), None)
    if base_pair is not None:
        groups.append(Group(main.baseline, main, main_runs, base_pair, method_named(main, main.baseline)))
    return groups


def controls_report(root: Path, main_name: str, others: list[str], method_name: str = "mikt",
                    grids: Path = ROOT / "benchmarks" / "grids") -> Path:
    main = load_grid(grids / f"{main_name}.toml")
    studies = [(load_grid(grids / f"{name}.toml"), snapshot_runs(root / name)) for name in others]
    main_runs = snapshot_runs(root / main_name)
    pairs: list[PairSpec] = []
    for grid, _ in studies:
        pairs += [p for p in grid.pairs if not any(same_pair(p, q) for q in pairs)]
    lines = ["# Controls and ablations", "",
             f"For each pair of {', '.join(f'`{n}`' for n in others)}: `{method_name}` and `{main.baseline}` from "
             f"`{main_name}` beside the control and ablation runs, every curve on the same seeds (those every grid "
             "of the pair has). Mean training return over the last 100 episodes at each mark (the last iteration "
             "at or before it), mean ± sample std (ddof 1) over the n finished seeds; the evals are the "
             "teacher-free student, deterministic, on fresh seeds. Run ids: each study's results.md.", ""]
    left_out: list[str] = []
    for pair in pairs:
        groups = main_groups(main, main_runs, pair, method_name)
        seed_sets, steps, marks = [], set(), []
        for grid, run_of in studies:
            for p in (p for p in grid.pairs if same_pair(p, pair)):
                groups += [Group(m.name, grid, run_of, p, m) for m in grid.methods]
                seed_sets.append(set(grid.seeds))
                steps.add(grid.steps)
                marks = marks or [m for m in grid.marks if m <= grid.steps] or [grid.steps]
        labels = [g.label for g in groups]
        if len(set(labels)) != len(labels):
            twice = sorted({label for label in labels if labels.count(label) > 1})
            raise SystemExit(f"two curves of {pair.name} have the same name: {twice}")
        if steps != {main.steps}:
            raise SystemExit(f"{pair.name}: the grids run {sorted(steps | {main.steps})} steps; the curves would not "
                             "be comparable")
        seeds = sorted(set.intersection(*seed_sets))
        found = curves_of(groups, seeds, marks)
        left_out += [problem for problem in found.left_out if problem not in left_out]
        slug = file_slug(pair.name)
        lines += [f"## {pair.name} (seeds {seeds})", "", *table_head(marks), *found.rows]
        compared = comparison_lines(compare_methods(found.per_seed))
        lines += compared
        if found.series:
            png_plot(found.series, root / f"controls-{slug}.png", pair.name, "mean episode return", found.bands,
                     order=labels, labels=partial_seed_labels(found.counts, len(seeds)))
            lines += ["", f"![learning curves](controls-{slug}.png)"]
        lines.append("")
    if left_out:
        lines += ["Completed runs left out (incomplete files):", "", *(f"- {problem}" for problem in left_out), ""]
    path = root / "controls.md"
    write_text_atomic(path, "\n".join(lines))
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root", type=Path, help="the folder holding the studies' result folders")
    parser.add_argument("--main", default="paper-2m")
    parser.add_argument("--controls", default="paper-2m-controls")
    parser.add_argument("--ablations", default="paper-2m-ablations")
    parser.add_argument("--method", default="mikt")
    args = parser.parse_args()
    print(controls_report(args.root, args.main, [args.controls, args.ablations], args.method))


if __name__ == "__main__":
    main()
