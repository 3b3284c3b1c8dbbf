"""Snapshots and restores of a study's runs, as `mikt study snapshot|restore` (studies.snapshots) does them.

    python benchmarks/snapshot_study.py RESULTS [--registry registry] [--in-flight] [--restore]

Kept so the commands written in the committed results' READMEs still work; new commands use the CLI.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from miktcli.errors import MiktError
from miktcli.studies.snapshots import restore, snapshot

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path)
    parser.add_argument("--registry", type=Path, default=ROOT / "registry")
    parser.add_argument("--in-flight", action="store_true",
                        help="also keep unfinished runs' checkpoints (the study must be stopped)")
    parser.add_argument("--restore", action="store_true", help="copy snapshots back into a registry lacking them")
    args = parser.parse_args()
    try:
        copied = restore(args.results, args.registry) if args.restore else snapshot(
            args.results, args.registry, in_flight=args.in_flight)
    except MiktError as err:
        sys.exit(f"error: {err}" + (f"\nhint: {err.hint}" if err.hint else ""))
    for c in copied:
        print(f"{c.run_id}  {c.cell}: {c.what}")


if __name__ == "__main__":
    main()
