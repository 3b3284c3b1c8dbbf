"""Where a registry is and how it was chosen, for the messages that say what was not found in it.

`cd sub && mikt eval` reads ./registry of `sub`, a folder that holds none; "no runs yet" alone reads as if the
runs were lost. So every such message names the folder it read (absolute) and how that folder was picked:
$MIKT_REGISTRY, the default ./registry of the working folder, or --registry.
"""

from __future__ import annotations

import os
from pathlib import Path

ENV_VAR = "MIKT_REGISTRY"
DEFAULT = Path("registry")  # the CLI's default (cli/common.py): ./registry of the working folder
HINT = f"run mikt from the folder that holds your registry, set {ENV_VAR}, or pass --registry"


def origin(registry: Path) -> str:
    """How `registry` was chosen. The CLI's option takes --registry, else $MIKT_REGISTRY, else ./registry: a
    path equal to the variable came from it, the default path with the variable unset is the default, and
    anything else was given."""
    given = os.environ.get(ENV_VAR)
    if given and Path(given) == Path(registry):
        return f"from ${ENV_VAR}"
    if not given and Path(registry) == DEFAULT:
        return f"the default ./registry, as {ENV_VAR} is unset"
    return "given by --registry"


def describe(registry: Path) -> str:
    """`/abs/path (how it was chosen[; no such folder])`: the folder a message says it read."""
    path = Path(registry)
    missing = "" if path.exists() else "; no such folder"
    return f"{path.resolve()} ({origin(path)}{missing})"
