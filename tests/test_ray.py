"""Studies on Ray: the same results as the serial study, resumable after an interruption, and a killed worker's
cell retried from its last handed-back checkpoint. Runs on a local 2-CPU Ray instance."""

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

pytestmark = pytest.mark.slow  # process-level: `pytest -m "not slow"` skips this module

ray = pytest.importorskip("ray")
runner = CliRunner()
GRID = """name = "raytiny"
steps = 6144
seeds = [0, 1]
marks = [6144]
eval_episodes = 1

[[pairs]]
from = ["tiny"]
to = "centipede-four"

[[methods]]
name = "mikt"
method = "mikt"
mikt = { coupling_schedule = "constant" }

[[methods]]
name = "vpg"
method = "vpg"
"""


@pytest.fixture(scope="module")
def local_ray():
    os.environ.setdefault("RAY_worker_niceness", "0")
    ray.init(num_cpus=2, include_dashboard=False, logging_level="ERROR", log_to_driver=False,
             runtime_env={"env_vars": {"OMP_NUM_THREADS": "1"}})
    yield
    ray.shutdown()


def numbers(out: Path) -> dict:
    """The summary numbers a study reports, without run ids (the section across pairs names none)."""
    summary = json.loads((out / "summary.json").read_text())
    across = summary.pop("across_pairs")
    pairs = {pair: {m: {k: v for k, v in s.items() if k != "runs"} for m, s in methods.items()}
             for pair, methods in summary.items()}
    return {"across_pairs": across, **pairs}


def setup(tmp_path, monkeypatch, name):
    registry = tmp_path / f"registry-{name}"
    monkeypatch.setenv("MIKT_REGISTRY", str(registry))
    r = runner.invoke(app, ["teacher", "train", "hopper", "--steps", "2048", "--name", "tiny"])
    assert r.exit_code == 0, r.output
    grid = tmp_path / "grid.toml"
    grid.write_text(GRID)
    return registry, grid


def test_parallel_study_equals_serial_and_survives_interruption_and_a_killed_worker(
        local_ray, tmp_path, monkeypatch):
    from miktcli.studies.grid import load_grid
    from miktcli.studies.ray_executor import FAULT_ENV, run_cells_on_ray
    from miktcli.studies.study import Study

    registry, grid = setup(tmp_path, monkeypatch, "serial")
    serial = tmp_path / "serial"
    r = runner.invoke(app, ["study", str(grid), "--out", str(serial)])
    assert r.exit_code == 0, r.output

    registry, grid = setup(tmp_path, monkeypatch, "ray")
    study = Study(load_grid(grid), tmp_path / "ray", registry)
    cells = study.prepare("test")
    assert [run.id for _, run in cells] == ["run2", "run3", "run4", "run5"]  # (mikt, vpg) x 2 seeds
    # 1. interrupted after the first chunk comes back: every cell stays resumable
    seen = {"calls": 0}

    def interrupt_soon(progress):
        seen["calls"] += 1
        if any(p.steps > 0 for p in progress):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        for _ in run_cells_on_ray(registry, cells, workers=2, address=None, eval_episodes=1, chunk_iterations=1,
                                  on_progress=interrupt_soon):
            pass
    statuses = [study.run_of(key).card.status for key, _ in cells]
    assert "completed" not in statuses and "interrupted" in statuses
    assert any(study.run_of(key).card.steps_done > 0 for key, _ in cells)
    # 2. resumed in parallel, with the worker of run2's second chunk (of this session) killed outright
    marker = tmp_path / "killed"
    os.environ[FAULT_ENV] = f"run2:1:{marker}"
    try:
        r = runner.invoke(app, ["study", str(grid), "--out", str(tmp_path / "ray"), "--workers", "2",
                                "--chunk-iterations", "1"])
    finally:
        del os.environ[FAULT_ENV]
    assert r.exit_code == 0, r.output
    assert marker.exists()  # the worker really died, and the cell was sent again from its last checkpoint
    assert "study: 0/4 cells completed, 2 training;" in r.output  # the overview line, stderr not a terminal
    assert numbers(tmp_path / "ray") == numbers(serial)
    assert all(study.run_of(key).card.status == "completed" for key, _ in cells)


def test_workers_without_ray_names_the_extra(tmp_path, monkeypatch):
    import miktcli.studies.ray_executor as executor

    def missing():
        from miktcli.errors import MiktError

        raise MiktError("studies on Ray need the ray extra", hint="pip install 'mikt[ray]'")

    monkeypatch.setattr(executor, "require_ray", missing)
    registry, grid = setup(tmp_path, monkeypatch, "noray")
    r = runner.invoke(app, ["study", str(grid), "--out", str(tmp_path / "o"), "--workers", "2"])
    assert r.exit_code == 1 and "pip install 'mikt[ray]'" in r.output
    assert not (registry / "runs" / "run2").exists()  # nothing was created before the check


def test_sigterm_stops_a_ray_study_like_ctrl_c(tmp_path):
    """ray.init replaces the process's SIGTERM handler; the study must still stop cleanly on SIGTERM. On the
    way: a cell waiting for the one worker shows as `queued`."""
    from miktcli.registry.runs import open_run

    registry = tmp_path / "registry"
    grid = tmp_path / "grid.toml"
    grid.write_text('name = "long"\nsteps = 2000000\nseeds = [0, 1]\n[[pairs]]\nfrom = ["x"]\nto = "hopper"\n'
                    '[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    proc = subprocess.Popen([sys.executable, "-m", "miktcli", "study", str(grid), "--out", str(tmp_path / "out"),
                             "--workers", "1", "--chunk-iterations", "1"],
                            env={**os.environ, "MIKT_REGISTRY": str(registry)},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not ((registry / "runs" / "run1" / "run.json").exists()
                   and open_run(registry, "run1").card.steps_done):  # until the first chunk of run1 came back
            assert proc.poll() is None and time.monotonic() < deadline, "the study ended or never trained"
            time.sleep(0.2)
        assert open_run(registry, "run1").status == "running"  # its next chunk is in flight
        assert open_run(registry, "run2").status == "queued"  # held by the study, waiting for the worker
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:  # never leave a 2M-step study behind
            proc.kill()
            proc.communicate()
    assert proc.returncode == 1, stderr
    assert "interrupted; run1 keeps its last complete checkpoint" in stderr, f"stderr:\n{stderr}"
    assert [open_run(registry, r).status for r in ("run1", "run2")] == ["interrupted", "not started"]


def _callers_handler(signum, frame):
    """A caller's SIGTERM handler, as the CLI's: a stop like Ctrl-C."""
    raise KeyboardInterrupt


def test_a_stop_request_waits_for_the_driver_loop_and_a_second_one_stops_at_once(pythons_ctrl_c):
    """Inside the driver loop Ctrl-C and SIGTERM only ask for a stop (a KeyboardInterrupt raised inside one of
    Ray's calls may be swallowed or wrapped by it) and call off the abort Ray's C-level handler arms; a second
    one raises at once; the handlers come back after. A handler of Ray's own is left in charge."""
    from miktcli.studies.ray_executor import stop_requests

    def rays(signum, frame):
        raise AssertionError("not reached")

    rays.__module__ = "ray._private.node"
    before = signal.signal(signal.SIGTERM, _callers_handler)
    try:
        with stop_requests() as stop:
            signal.alarm(30)  # as Ray's C-level SIGTERM handler arms one, to abort the process 3 s on
            signal.raise_signal(signal.SIGTERM)
            assert stop.is_set()  # asked, nothing raised
            assert signal.alarm(0) == 0  # and the abort was called off: the clean stop takes longer than 3 s
            with pytest.raises(KeyboardInterrupt):
                signal.raise_signal(signal.SIGINT)
        assert signal.getsignal(signal.SIGTERM) is _callers_handler
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        signal.signal(signal.SIGTERM, rays)
        with stop_requests():
            assert signal.getsignal(signal.SIGTERM) is rays
    finally:
        signal.signal(signal.SIGTERM, before)


def test_a_stop_that_comes_with_the_last_chunk_in_flight_still_stops_the_study():
    """The last chunk comes back during the wait in which the stop was asked for: nothing is left in flight or
    queued, and the loop must still raise (so the caller cancels and says how to resume), not end as if done."""
    from types import SimpleNamespace

    from miktcli.studies.ray_executor import RayDriver

    def wait(refs, num_returns, timeout):
        signal.raise_signal(signal.SIGTERM)  # arrives while Ray waits
        return refs[:1], refs[1:]

    driver = object.__new__(RayDriver)
    driver.ray = SimpleNamespace(wait=wait)
    driver.queue, driver.in_flight, driver.capacity, driver.progress = [], {"ref": "run1"}, 1, {}
    taken = []
    driver._take_back = lambda ref, submit_next=True: taken.append((driver.in_flight.pop(ref), submit_next)) or []
    before = signal.signal(signal.SIGTERM, _callers_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            list(driver.run(None))
    finally:
        signal.signal(signal.SIGTERM, before)
    assert taken == [("run1", False)]  # the chunk that came back is kept, and no next one was sent
