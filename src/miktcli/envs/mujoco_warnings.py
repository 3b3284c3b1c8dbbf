"""MuJoCo's warnings, counted in the process instead of appended to MUJOCO_LOG.TXT in the user's directory.

MuJoCo's default handler writes every warning (a diverging simulation: "Nan, Inf or huge value in QACC …")
to a log file in the working directory and to stdout. The library never prints and never litters, so the
handler is replaced once per process and training reports the count in each iteration's metrics.
"""

from __future__ import annotations

import mujoco

_state = {"installed": False, "count": 0, "last": ""}


def _record(message: str) -> None:
    _state["count"] += 1
    _state["last"] = message


def capture_mujoco_warnings() -> None:
    """Route MuJoCo's warnings to the counter (idempotent; the handler is process-wide in MuJoCo)."""
    if not _state["installed"]:
        mujoco.set_mju_user_warning(_record)
        _state["installed"] = True


def mujoco_warning_count() -> int:
    return _state["count"]


def last_mujoco_warning() -> str:
    return _state["last"]
