"""Example study grids that ship inside the package (`grids/*.toml`), so `mikt study run --example NAME` works
from an installed wheel, where the repository's own grids are absent.

An example names only packaged teachers and shipped environments, and no file relative to itself (a reference
result), so it runs from any folder; tests/test_study_examples.py checks both. Its first line, a `# ` comment,
is its one-line description.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from miktcli.errors import MiktError
from miktcli.outfiles import atomic_output

GRIDS = Path(__file__).resolve().parent / "grids"


@dataclass(frozen=True)
class Example:
    name: str
    path: Path
    description: str


def _description(path: Path) -> str:
    first = path.read_text(encoding="utf-8").splitlines()[:1]
    return first[0].removeprefix("#").strip() if first and first[0].startswith("#") else ""


def examples() -> list[Example]:
    return [Example(p.stem, p, _description(p)) for p in sorted(GRIDS.glob("*.toml"))]


def example(name: str) -> Example:
    """The example called `name`; an unknown name is one line listing the known ones."""
    found = {e.name: e for e in examples()}
    if name not in found:
        raise MiktError(f"unknown example grid '{name}'; known: {', '.join(found) or '(none)'}",
                        hint="`mikt study examples` lists them with what each one runs")
    return found[name]


def copy_example(name: str, to: str | Path | None = None) -> Path:
    """Copy an example grid out to edit it: to `to` (a file, or a folder for NAME.toml: one that exists, or a
    path ending in '/'), by default ./NAME.toml. An existing file is never overwritten (it may be the user's
    edited copy)."""
    source = example(name).path
    target = Path(to) if to is not None else Path(source.name)
    if target.is_dir() or str(to).endswith(("/", os.sep)):  # Path() drops the slash that says "a folder"
        target = target / source.name
    if target.exists():
        raise MiktError(f"{target} already exists; not overwriting it",
                        hint="remove it first, or pass --to another path")
    if target.suffix != ".toml":
        raise MiktError(f"{target} is not a .toml path (a grid file is TOML)", hint="pass --to NAME.toml")
    with atomic_output(target, ".toml") as tmp:
        shutil.copyfile(source, tmp)
    return target
