"""mikt: mutual-information based knowledge transfer across robot morphologies."""

import os

__version__ = "0.2.0"

# MuJoCo picks its GL backend when it is first imported. Without a display, GLFW cannot open a
# context, so default to Mesa's EGL (works on CPU-only machines); an explicit MUJOCO_GL wins.
if not os.environ.get("DISPLAY"):
    os.environ.setdefault("MUJOCO_GL", "egl")
