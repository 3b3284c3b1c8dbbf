"""MuJoCo's GL backend, loaded only to render.

`import mujoco` loads the GL backend that MUJOCO_GL names, and fails on a value it does not know (a typo) or a
backend whose library is missing (osmesa without libOSMesa). Importing it that way made every command fail,
even those that never render (`mikt runs`, `teacher list`, a transfer). So mikt imports mujoco first with its GL
disabled, and loads the backend asked for when an env is made to render, with one error line if it cannot."""

from __future__ import annotations

import importlib
import os
import sys

from miktcli.errors import MiktError

RENDER_HINT = ("MUJOCO_GL must be egl (Mesa's EGL, the default without a display), osmesa (needs libOSMesa and "
               "PYOPENGL_PLATFORM=osmesa) or glfw (needs a display); see docs/guide/install.md")
_loaded = False


def import_mujoco_without_gl() -> None:
    """Import mujoco with no GL backend, leaving MUJOCO_GL as it was for `load_gl_backend` (and gymnasium)."""
    if "mujoco" in sys.modules:  # imported before mikt was: its backend is already chosen, and it imported
        return
    asked = os.environ.get("MUJOCO_GL")
    os.environ["MUJOCO_GL"] = "disable"
    try:
        import mujoco  # noqa: F401
    finally:
        if asked is None:
            del os.environ["MUJOCO_GL"]
        else:
            os.environ["MUJOCO_GL"] = asked


def load_gl_backend() -> None:
    """Load the backend MUJOCO_GL names, the way mujoco would have at import; a one-line error if it cannot."""
    global _loaded
    if _loaded:
        return
    from mujoco.rendering.classic import gl_context

    asked = os.environ.get("MUJOCO_GL", "")
    try:
        importlib.reload(gl_context)  # mujoco's own choice of backend, now under the user's MUJOCO_GL
    except Exception as err:  # noqa: BLE001 - a bad value (RuntimeError), a missing library (AttributeError, OSError)
        raise MiktError(f"MUJOCO_GL={asked!r}: the GL backend for offscreen rendering cannot be loaded "
                        f"({type(err).__name__}: {err})", hint=RENDER_HINT) from None
    if asked.lower().strip() in ("disable", "disabled", "off", "false", "0") \
            or getattr(gl_context, "GLContext", None) is None:
        raise MiktError(f"MUJOCO_GL={asked!r} turns rendering off", hint=RENDER_HINT)
    _loaded = True
