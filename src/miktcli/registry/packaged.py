"""The teachers that ship inside the package: a read-only layer below the local registry.

A wheel carries the latest version of each teacher the repository ships (pyproject.toml lists them under
`force-include`) in `miktcli/_teachers/NAME/vN.safetensors`, the same layout as `registry/teachers/`. In a
source checkout the same layer is the checkout's own `registry/teachers/`, latest version of each name: the rule
that chooses what the wheel carries (tests/test_wheel.py checks that pyproject.toml follows it).

Nothing is ever written here: publishing writes into the local registry only.
`MIKT_PACKAGED_TEACHERS=0` hides the layer (a registry that holds only what you trained or imported).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from miktcli.errors import MiktError

ENV_VAR = "MIKT_PACKAGED_TEACHERS"
VERSION_FILE_RE = re.compile(r"^v(\d+)\.safetensors$")
_PACKAGE = Path(__file__).resolve().parents[1]  # .../miktcli


def _enabled() -> bool:
    value = os.environ.get(ENV_VAR, "1")
    if value not in ("0", "1"):
        raise MiktError(f"{ENV_VAR}={value!r}: expected 0 (hide the packaged teachers) or 1 (the default)")
    return value == "1"


def _latest_files(root: Path) -> dict[str, tuple[int, Path]]:
    found: dict[str, tuple[int, Path]] = {}
    for folder in sorted(p for p in root.iterdir() if p.is_dir()):
        numbers = [int(m.group(1)) for p in folder.iterdir() if (m := VERSION_FILE_RE.fullmatch(p.name))]
        if numbers:
            found[folder.name] = (max(numbers), folder / f"v{max(numbers)}.safetensors")
    return found


def packaged_root() -> Path | None:
    """The folder the packaged layer is read from: the wheel's copy, else the source checkout's registry."""
    wheel = _PACKAGE / "_teachers"
    if wheel.is_dir():
        return wheel
    checkout = _PACKAGE.parents[1]
    if (checkout / "pyproject.toml").is_file() and (checkout / "registry" / "teachers").is_dir():
        return checkout / "registry" / "teachers"
    return None


def packaged_teachers() -> dict[str, tuple[int, Path]]:
    """name → (version, file) of every packaged teacher; empty when the layer is hidden or absent."""
    if not _enabled():
        return {}
    root = packaged_root()
    return _latest_files(root) if root is not None else {}
