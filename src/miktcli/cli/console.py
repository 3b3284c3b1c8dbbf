"""Two consoles: data goes to stdout, everything else (progress, warnings, errors) to stderr."""

from __future__ import annotations

import json
import os
from typing import Any

from rich.console import Console

out = Console(highlight=False, soft_wrap=True, width=None if os.isatty(1) else 160)
err = Console(stderr=True, highlight=False, soft_wrap=True)


def debug_enabled() -> bool:
    return os.environ.get("MIKT_DEBUG", "") not in ("", "0")


def print_json(data: Any) -> None:
    # Plain print: Rich would wrap long lines and break the JSON for scripts.
    print(json.dumps(data, indent=2, default=str))
