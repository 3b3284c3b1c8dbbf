"""A bad or unavailable MUJOCO_GL: mujoco's GL backend loads only to render, so commands that
never render keep working, and every rendering failure (eval's frame capture included) is one `Error:` line
with a hint. In child processes: mujoco reads MUJOCO_GL once per process."""

import ctypes.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

SRC = str(Path(__file__).parents[1] / "src")


def mikt_with_gl(gl: str, *args, registry: Path, code: int = 0) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": SRC, "MUJOCO_GL": gl, "MIKT_REGISTRY": str(registry), "COLUMNS": "200"}
    env.pop("DISPLAY", None)
    env.pop("PYOPENGL_PLATFORM", None)
    r = subprocess.run([sys.executable, "-m", "miktcli", *map(str, args)], capture_output=True, text=True,
                       env=env, timeout=600)
    assert r.returncode == code, r.stdout + r.stderr
    return r


def one_line_error(stderr: str) -> str:
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 2 and lines[0].startswith("Error: ") and lines[1].startswith("Hint: MUJOCO_GL must be"), \
        stderr
    return lines[0]


BAD = ["typo"] + ([] if ctypes.util.find_library("OSMesa") else ["osmesa"])  # osmesa without libOSMesa


@pytest.mark.slow  # process-level: runs mikt in a subprocess
@pytest.mark.parametrize("gl", BAD)
def test_a_bad_mujoco_gl_leaves_commands_that_do_not_render_working(tmp_path, gl):
    reg = tmp_path / "reg"
    mikt_with_gl(gl, "transfer", "--to", "hopper", "--method", "vpg", "--steps", 2048, "--eval-episodes", 1,
                 registry=reg)
    assert "run1" in mikt_with_gl(gl, "runs", registry=reg).stdout
    mikt_with_gl(gl, "teacher", "list", registry=reg)
    assert "centipede-four" in mikt_with_gl(gl, "envs", registry=reg).stdout
    # rendering itself fails in one line, naming the variable, and writes nothing
    error = one_line_error(mikt_with_gl(gl, "envs", "render", "hopper", "--out", tmp_path / "x.png", registry=reg,
                                        code=1).stderr)
    assert f"MUJOCO_GL='{gl}'" in error and not (tmp_path / "x.png").exists()
    error = one_line_error(mikt_with_gl(gl, "eval", "run1", "--episodes", 1, "--video", tmp_path / "v.mp4",
                                        registry=reg, code=1).stderr)
    assert f"MUJOCO_GL='{gl}'" in error and not (tmp_path / "v.mp4").exists()


@pytest.mark.slow  # process-level: runs mikt in a subprocess
@pytest.mark.parametrize("env_name", ["centipede-four", "hopper"])
def test_glfw_without_a_display_is_one_line_without_stray_warnings(tmp_path, env_name):
    r = mikt_with_gl("glfw", "envs", "render", env_name, "--out", tmp_path / "x.png", registry=tmp_path / "reg",
                     code=1)
    assert "offscreen rendering failed" in one_line_error(r.stderr)
    assert "GLFWError" not in r.stderr


def test_eval_frame_capture_failures_are_one_line(monkeypatch, registry, tmp_path):
    # a backend that loads but fails on the first frame: eval's capture goes through the same error as render
    from helpers import mikt
    from miktcli.envs.centipede import CentipedeEnv

    mikt("transfer", "--to", "centipede-four", "--method", "vpg", "--steps", 2048, "--eval-episodes", 1)

    def broken(self):
        raise OSError("no GL context")

    monkeypatch.setattr(CentipedeEnv, "render", broken)
    r = mikt("eval", "run1", "--episodes", 1, "--video", tmp_path / "v.mp4", code=1)
    assert "offscreen rendering failed (OSError: no GL context)" in r.output and not (tmp_path / "v.mp4").exists()
