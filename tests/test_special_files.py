"""mikt reads only regular files: a FIFO, a device or a socket in a file's place is refused in one line, at
once, never waited on or read without end."""

import json
import os
import subprocess
import sys

import pytest

from helpers import mikt, robot_with_mesh_and_include


def run_cli(*args, registry, timeout=60):
    """The CLI in its own process, with a deadline: a FIFO opened blindly would block it for good."""
    env = {**os.environ, "MIKT_REGISTRY": str(registry)}
    return subprocess.run([sys.executable, "-m", "miktcli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=env)


@pytest.fixture(scope="module")
def trained_registry(tmp_path_factory):
    """A registry with a tiny teacher and one finished transfer, trained once for the module: each test breaks
    its own copy (the FIFO cases differ only in the file they replace)."""
    registry = tmp_path_factory.mktemp("trained") / "registry"
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("MIKT_REGISTRY", str(registry))
        mikt("teacher", "train", "hopper", "--steps", 2048, "--name", "tiny")
        run = json.loads(mikt("transfer", "--from", "tiny", "--to", "hopper", "--steps", 2048, "--eval-episodes",
                              1, "--coupling-schedule", "constant", "--json").stdout)["run"]
    return registry, run


@pytest.fixture()
def finished_run(registry, trained_registry):
    import shutil

    template, run = trained_registry
    shutil.copytree(template, registry)
    return registry / "runs" / run


@pytest.mark.parametrize("victim", ["checkpoint.safetensors", "metrics.jsonl", "student.safetensors"])
def test_a_fifo_in_a_run_folder_is_refused_not_waited_on(finished_run, registry, victim):
    path = finished_run / victim
    path.unlink()
    os.mkfifo(path)
    command = {"checkpoint.safetensors": ("eval", finished_run.name, "--with-teacher", "--episodes", 1),
               "metrics.jsonl": ("inspect", finished_run.name, "--curve"),
               "student.safetensors": ("eval", finished_run.name, "--episodes", 1)}[victim]
    result = run_cli(*command, registry=registry)
    assert result.returncode == 1, result.stderr
    assert "a FIFO, not a regular file" in result.stderr and "Traceback" not in result.stderr


def test_a_device_as_metrics_is_refused_not_read_to_the_end(finished_run, registry):
    path = finished_run / "metrics.jsonl"
    path.unlink()
    path.symlink_to("/dev/zero")
    result = run_cli("inspect", finished_run.name, "--curve", registry=registry)
    assert result.returncode == 1 and "a device, not a regular file" in result.stderr


@pytest.mark.slow
def test_a_fifo_as_a_teacher_file_or_spec_or_grid_is_refused(registry, tmp_path, teacher):
    teacher = registry / "teachers" / "tiny" / "v1.safetensors"
    teacher.unlink()
    os.mkfifo(teacher)
    result = run_cli("eval", "tiny", "--episodes", 1, registry=registry)
    assert result.returncode == 1 and "a FIFO, not a regular file" in result.stderr
    grid = tmp_path / "grid.toml"
    os.mkfifo(grid)
    result = run_cli("study", grid, "--out", tmp_path / "out", registry=registry)
    assert result.returncode == 1 and "a FIFO, not a regular file" in result.stderr


def test_a_metrics_line_or_file_past_its_limit_is_refused(finished_run, monkeypatch):
    from miktcli import limits
    from miktcli.errors import MiktError
    from miktcli.registry.runs import open_run

    run = open_run(finished_run.parent.parent, finished_run.name)
    monkeypatch.setattr(limits, "MAX_METRICS_LINE_BYTES", 100)
    with pytest.raises(MiktError, match="a line of more than 100 bytes"):
        run.read_metrics()
    monkeypatch.setattr(limits, "MAX_METRICS_LINE_BYTES", 1 << 20)
    monkeypatch.setattr(limits, "MAX_METRICS_BYTES", 100)
    with pytest.raises(MiktError, match="more than the 100 bytes"):
        run.read_metrics()


@pytest.mark.parametrize("victim", ["motors.xml", "meshes/foot.obj"])
def test_a_fifo_as_an_include_or_a_mesh_is_refused_before_mujoco_opens_it(tmp_path, monkeypatch, victim):
    xml = robot_with_mesh_and_include(tmp_path / "robot")
    (tmp_path / "robot" / victim).unlink()
    os.mkfifo(tmp_path / "robot" / victim)
    (tmp_path / "specs").mkdir()
    monkeypatch.setenv("MIKT_ENVSPECS", str(tmp_path / "specs"))
    result = run_cli("envs", "add", xml, "--name", "bot", registry=tmp_path / "registry")
    assert result.returncode == 1 and "a FIFO, not a regular file" in result.stderr, result.stderr
    assert not (tmp_path / "specs" / "bot.toml").exists()


def test_model_files_past_their_bounds_are_refused_before_mujoco_reads_them(tmp_path, monkeypatch):
    from miktcli import limits

    xml = robot_with_mesh_and_include(tmp_path / "robot")
    (tmp_path / "specs").mkdir()
    monkeypatch.setenv("MIKT_ENVSPECS", str(tmp_path / "specs"))
    monkeypatch.setattr(limits, "MAX_MODEL_FILE_BYTES", 100)  # foot.obj and bot.xml are larger
    assert "bytes, more than the 100 this kind of file may take" in mikt("envs", "add", xml, "--name", "b",
                                                                          code=1).output
    monkeypatch.setattr(limits, "MAX_MODEL_FILE_BYTES", 1 << 20)
    monkeypatch.setattr(limits, "MAX_MODEL_BYTES", 500)  # each file fits, all of them together do not
    assert "the model's files pass 500 bytes together" in mikt("envs", "add", xml, "--name", "b", code=1).output
    assert not list((tmp_path / "specs").iterdir())
