"""One driver per study folder: a second `mikt study` on the same --out is refused (issue 37 B)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from miktcli.cli.app import app

runner = CliRunner()
SRC = Path(__file__).resolve().parents[1] / "src"


def write_grid(tmp_path, steps=2048, seeds="[0]"):
    grid = tmp_path / "g.toml"
    grid.write_text(f'name = "g"\nsteps = {steps}\nseeds = {seeds}\n[[pairs]]\nfrom = ["x"]\nto = "hopper"\n'
                    '[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    return grid


def test_a_second_driver_on_the_same_study_folder_is_refused(registry, tmp_path):
    grid, out = write_grid(tmp_path, steps=2048 * 40), tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": f"{SRC}{os.pathsep}{os.environ.get('PYTHONPATH', '')}",
           "MIKT_REGISTRY": str(registry)}
    first = subprocess.Popen([sys.executable, "-m", "miktcli", "study", str(grid), "--out", str(out)], env=env,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300
        while not (out / "state.json").exists():  # the first driver has prepared its cell and trains it
            assert first.poll() is None, first.stderr.read()
            assert time.monotonic() < deadline, "the first driver never prepared its cell"
            time.sleep(0.2)
        second = runner.invoke(app, ["study", str(grid), "--out", str(out)])
        assert first.poll() is None, "the first driver ended before the second started: make its cell longer"
        assert second.exit_code == 1, second.output
        assert f"Error: {out} is driven by another `mikt study` (pid {first.pid})" in second.output
        assert json.loads((out / "state.json").read_text()) == {"->hopper|vpg|0": "run1"}
        assert sorted(p.name for p in (registry / "runs").iterdir()) == ["run1"]  # the second created nothing
        # reading the folder meanwhile is fine
        report = runner.invoke(app, ["study", str(grid), "--out", str(out), "--report-only"])
        assert report.exit_code == 0, report.output
    finally:
        first.send_signal(signal.SIGTERM)
        first.wait(timeout=120)


def test_the_lock_is_held_for_the_whole_study_and_released_after(registry, tmp_path):
    from miktcli.errors import MiktError
    from miktcli.studies.grid import load_grid
    from miktcli.studies.study import Study

    grid = load_grid(write_grid(tmp_path))
    driver, other = Study(grid, tmp_path / "out", registry), Study(grid, tmp_path / "out", registry)
    with driver.driving():
        driver.prepare("test")
        with pytest.raises(MiktError, match=f"is driven by another `mikt study` \\(pid {os.getpid()}\\)"):
            other.prepare("test")
        driver.prepare("test")  # the driver itself may prepare again (a resumed serial loop does)
    assert [key for key, _ in other.prepare("test")] == ["->hopper|vpg|0"]  # free again once the driver ends
    # and a driver that took the lock reads state.json as it is now, not as it was when it was constructed
    assert other.cells == driver.cells == {"->hopper|vpg|0": "run1"}


def test_a_driver_reads_state_written_after_it_was_constructed(registry, tmp_path):
    from miktcli.studies.grid import load_grid
    from miktcli.studies.study import Study

    grid = load_grid(write_grid(tmp_path))
    early, first = Study(grid, tmp_path / "out", registry), Study(grid, tmp_path / "out", registry)
    first.prepare("test")  # another driver prepared the cell since `early` read the folder
    assert [run.id for _, run in early.prepare("test")] == ["run1"]  # the same run, not a second one

