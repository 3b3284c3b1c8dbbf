"""pip install and go: the built wheel, alone in a fresh venv, run from an empty folder, lists the packaged
teachers, transfers from one and runs an example grid; and pyproject.toml ships exactly the latest version of
each teacher."""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import re
import site
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # process-level: `pytest -m "not slow"` skips this module

ROOT = Path(__file__).resolve().parents[1]
VERSION_RE = re.compile(r"^registry/teachers/([^/]+)/v(\d+)\.safetensors$")


def tracked_teacher_files() -> list[str]:
    """The teacher files of the repository (git's list: a teacher trained into a checkout is not shipped)."""
    try:
        out = subprocess.run(["git", "ls-files", "registry/teachers"], cwd=ROOT, capture_output=True, text=True,
                             check=True).stdout
        return out.split()
    except (OSError, subprocess.CalledProcessError):  # a source tree without git: what is there
        return [str(p.relative_to(ROOT)) for p in (ROOT / "registry" / "teachers").glob("*/v*.safetensors")]


def latest_teacher_versions() -> dict[str, int]:
    """name -> the highest version the repository holds: what the wheel ships."""
    latest: dict[str, int] = {}
    for path in tracked_teacher_files():
        if m := VERSION_RE.fullmatch(path):
            latest[m.group(1)] = max(latest.get(m.group(1), 0), int(m.group(2)))
    return latest


def test_pyproject_ships_the_latest_version_of_each_teacher():
    latest = latest_teacher_versions()
    assert latest, "the repository ships no teachers"
    want = {f"registry/teachers/{n}/v{v}.safetensors": f"miktcli/_teachers/{n}/v{v}.safetensors"
            for n, v in latest.items()}
    forced = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["hatch"]["build"]["targets"]["wheel"][
        "force-include"]
    assert {k: v for k, v in forced.items() if v.startswith("miktcli/_teachers/")} == want


def _run(args, **kw) -> subprocess.CompletedProcess:
    result = subprocess.run([str(a) for a in args], capture_output=True, text=True, **kw)
    assert result.returncode == 0, f"{args}\n{result.stdout}\n{result.stderr}"
    return result


def _tree_digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file() and "__pycache__" not in p.parts}


def test_the_wheel_alone_runs_from_an_empty_folder(tmp_path):
    # 1. the wheel, as `pip wheel .` builds it (hatchling from the venv when there, else pip fetches it)
    dist = tmp_path / "dist"
    isolation = ["--no-build-isolation"] if importlib.util.find_spec("hatchling") else []
    _run([sys.executable, "-m", "pip", "wheel", ROOT, "--no-deps", "-q", "-w", dist, *isolation])
    (wheel,) = dist.glob("mikt-*.whl")
    assert wheel.stat().st_size < 2_000_000  # teachers are ~100 KB each: only the latest of each ships

    # 2. a fresh venv that sees this interpreter's dependencies (torch, mujoco, ...) through a plain .pth line
    # (plain lines do not run the .pth files there, so an editable mikt in this venv stays out) and gets mikt
    # itself only from the wheel
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv])
    python = venv / "bin" / "python"
    purelib = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"]).stdout.strip())
    (purelib / "_deps_of_the_test_venv.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    _run([sys.executable, "-m", "pip", "--python", python, "install", "--no-deps", "--no-index", "-q", wheel])

    empty = tmp_path / "empty"
    empty.mkdir()
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "MIKT_REGISTRY", "MIKT_ENVSPECS", "MIKT_PACKAGED_TEACHERS")}
    env["PYTHONDONTWRITEBYTECODE"] = "1"

    def run(*args):
        return _run(args, cwd=empty, env=env)

    where = Path(run(python, "-c", "import miktcli; print(miktcli.__file__)").stdout.strip())
    assert where.is_relative_to(venv), where  # not this checkout's src/, not an editable install
    package = where.parent
    before = _tree_digest(package)

    mikt = venv / "bin" / "mikt"
    listed = json.loads(run(mikt, "teacher", "list", "--json").stdout)
    # exactly the latest version of each teacher, all packaged, none broken (a teacher first trained at v1, such
    # as centipede-eight, ships as v1; an older version of any other is not shipped)
    assert {(r["ref"], r["source"]) for r in listed} == {
        (f"{name}@v{version}", "packaged") for name, version in latest_teacher_versions().items()}
    assert all(r["error"] is None for r in listed)
    assert "packaged" in run(mikt, "teacher", "list").stdout

    run(mikt, "transfer", "--from", "centipede-four", "--to", "centipede-six", "--steps", 2048,
        "--eval-episodes", 1)
    card = json.loads((empty / "registry" / "runs" / "run1" / "run.json").read_text())
    assert card["teachers"][0]["name"] == "centipede-four" and card["teachers"][0]["version"] == 2

    # the run's teacher-free student becomes a teacher, and teaches the next body
    assert run(mikt, "teacher", "add", "run1", "--name", "six-from-four").stdout.strip() == "six-from-four@v1"
    run(mikt, "transfer", "--from", "six-from-four", "--to", "centipede-eight", "--steps", 2048,
        "--eval-episodes", 1)
    card = json.loads((empty / "registry" / "runs" / "run2" / "run.json").read_text())
    assert card["teachers"][0]["name"] == "six-from-four"

    # a robot of one's own: the spec the package writes is decided from the model (home keyframe, no bonus)
    quadruped = ROOT / "tests" / "fixtures" / "robots" / "quadruped" / "scene.xml"
    added = run(mikt, "envs", "add", quadruped, "--name", "quad")
    assert "resets to the model's 'home' keyframe" in added.stderr and "probe, a zero action" in added.stderr
    assert 'keyframe = "home"' in (empty / "envspecs" / "quad.toml").read_text()

    # a teacher trained here is numbered above the packaged ones and written here, never into the package
    out = run(mikt, "teacher", "train", "hopper", "--steps", 2048).stdout.strip()
    assert out == "hopper@v3" and (empty / "registry" / "teachers" / "hopper" / "v3.safetensors").is_file()

    # the example grids ship too (benchmarks/ does not): one runs by name, its results in ./studies
    assert "tiny" in {e["name"] for e in json.loads(run(mikt, "study", "examples", "--json").stdout)}
    run(mikt, "study", "--example", "tiny")
    assert (empty / "studies" / "tiny" / "results.md").is_file()
    assert _tree_digest(package) == before


@pytest.mark.parametrize("value", ["yes", "2"])
def test_the_packaged_layer_switch_takes_0_or_1(registry, monkeypatch, value):
    from miktcli.errors import MiktError
    from miktcli.registry.teachers import list_names

    monkeypatch.setenv("MIKT_PACKAGED_TEACHERS", value)
    with pytest.raises(MiktError, match="expected 0"):
        list_names(registry)
