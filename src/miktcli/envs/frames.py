"""Offscreen frames to PNG and MP4; works headless through Mesa (EGL or OSMesa), no display, no GPU."""

from __future__ import annotations

import warnings
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from miktcli.envs.gl_backend import RENDER_HINT
from miktcli.errors import MiktError
from miktcli.outfiles import atomic_output


def render_frame(env) -> np.ndarray:
    """One RGB frame from an env made with render_mode='rgb_array'. A failure is one error, with what the GL
    library warned about folded into it (GLFW warns "DISPLAY is missing" before the error that follows)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            frame = env.render()
        except Exception as err:  # the GL backends raise a zoo of types; name the fix instead
            said = "; ".join(dict.fromkeys(str(w.message) for w in caught))
            raise MiktError(
                f"offscreen rendering failed ({type(err).__name__}: {err})" + (f"; the GL library said: {said}"
                                                                               if said else ""),
                hint=RENDER_HINT,
            ) from None
    for w in caught:  # a frame came: what was said is worth showing as it would have been
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if frame is None:
        raise MiktError("the environment returned no frame; was it made with render_mode='rgb_array'?")
    return np.asarray(frame)


def save_png(frame: np.ndarray, path: Path) -> Path:
    import imageio.v3 as iio

    with atomic_output(path, ".png") as tmp:
        iio.imwrite(tmp, frame, extension=".png")
    return Path(path)


def save_mp4(frames: Iterable[np.ndarray], path: Path, fps: int) -> Path:
    import imageio.v2 as imageio

    # ffmpeg itself stays quiet (its lines would follow our one-line error); a failure is told by the writer
    with atomic_output(path, ".mp4") as tmp, imageio.get_writer(tmp, fps=fps, codec="libx264",
                                                                 macro_block_size=16,
                                                                 ffmpeg_log_level="quiet") as writer:
        for frame in frames:
            writer.append_data(frame)
    return Path(path)
