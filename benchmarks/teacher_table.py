"""The shipped teachers as a Markdown table (from their cards) and one PNG of their learning curves.

    python benchmarks/teacher_table.py [--version 2]

Reads registry/teachers/*/vN.safetensors headers and benchmarks/results/teachers/v2/*-metrics.jsonl; writes
benchmarks/results/teachers/v2/curves.png and prints the table of docs/guide/teachers.md (Teachers shipped in
registry/).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from miktcli.registry.teachers import list_names, read_teacher_card, teachers_dir
from miktcli.stats.plots import png_plot

ROOT = Path(__file__).resolve().parents[1]
AUTHORS = {  # final mean return of the authors' PPO logs, 2M steps, 5 seeds (shared/reference)
    "centipede-four": [3601, 2997, 1683, 2625, 1805],
    "hopper": [3429, 1784, 3140, 2169, 1754],
}


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--version", type=int, default=2)
    parser.add_argument("--registry", type=Path, default=ROOT / "registry")
    args = parser.parse_args(argv)
    curves_dir = ROOT / "benchmarks" / "results" / "teachers" / f"v{args.version}"
    print("| teacher | steps | actions | final mean return (best) | authors' logs (PPO, 2M steps, 5 seeds) |")
    print("|---|---|---|---|---|")
    series = {}
    for name in list_names(args.registry):
        path = teachers_dir(args.registry) / name / f"v{args.version}.safetensors"
        if not path.exists():
            continue
        card = read_teacher_card(path)
        authors = AUTHORS.get(card.env)
        ref = " / ".join(map(str, authors)) + f" (mean {sum(authors) / len(authors):,.0f})" if authors else "—"
        best = f" ({card.best_return:,.0f})" if card.best_return is not None else ""
        final = f"{card.final_return:,.0f}{best}" if card.final_return is not None else "—"
        actions = "clipped" if card.clip_actions_for_env else "raw"
        print(f"| `{card.ref}` | {card.steps:,} | {actions} | {final} | {ref} |")
        metrics = curves_dir / f"{card.env}-metrics.jsonl"
        if metrics.exists():
            rows = [json.loads(line) for line in metrics.read_text().splitlines() if line.strip()]
            series[card.ref] = [(r["steps"], r["return_mean"]) for r in rows if r.get("return_mean") is not None]
    if series:
        png_plot(series, curves_dir / "curves.png", f"teachers v{args.version}: training return",
                 "mean episode return (last 100)")
        print(f"\n![teacher learning curves]({(curves_dir / 'curves.png').relative_to(ROOT)})")


if __name__ == "__main__":
    main(sys.argv[1:])
