"""Two consoles: data goes to stdout, everything else (progress, warnings, errors) to stderr.

Outside text (teacher names, cards, run files, arguments) must never act on the terminal: Rich markup in it
(`[/x]`) is shown as written, and control characters (an ESC that would clear the screen) are shown
escaped (`\\x1b`). Both consoles do that for every string they render, tables included; styled output is
built from `Text` pieces, never from markup strings.
"""

from __future__ import annotations

import json
import os
import re
import sys
from typing import Any

from rich.console import Console
from rich.text import Text

# C0 controls except tab and newline, DEL, and the C1 range (8-bit CSI among them).
_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]")


def clean(text: object) -> str:
    """Outside text made inert for a terminal: control characters shown as escapes."""
    return _CONTROL.sub(lambda m: f"\\x{ord(m.group()):02x}", str(text))


class SafeConsole(Console):
    """A Console that renders every string literally: no markup, no emoji codes, no control characters."""

    def render_str(self, text: str, **kwargs: Any) -> Text:
        kwargs.update(markup=False, emoji=False)
        return super().render_str(clean(text), **kwargs)


out = SafeConsole(highlight=False, soft_wrap=True, width=None if os.isatty(1) else 160)
err = SafeConsole(stderr=True, highlight=False, soft_wrap=True)


def print_error(message: object, hint: object | None = None) -> None:
    """`Error: …` (and `Hint: …`) on stderr. Cannot raise: a broken console falls back to plain writes."""
    try:
        err.print(Text.assemble(("Error:", "bold red"), " ", clean(message)))
        if hint:
            err.print(f"Hint: {hint}")
    except Exception:  # noqa: BLE001 - the error printer is the last line of defence
        text = f"Error: {clean(message)}\n" + (f"Hint: {clean(hint)}\n" if hint else "")
        sys.stderr.write(text.encode("ascii", "backslashreplace").decode("ascii"))


def debug_enabled() -> bool:
    return os.environ.get("MIKT_DEBUG", "") not in ("", "0")


def print_json(data: Any) -> None:
    # Plain print: Rich would wrap long lines and break the JSON for scripts. json.dumps escapes controls.
    print(json.dumps(data, indent=2, default=str))


def print_data(text: object) -> None:
    """One line of data on stdout (a ref, a run id, a path), made inert like everything else."""
    print(clean(text))
