"""Running a study: its cells are prepared once (state.json written in batches, a preparation stopped part way
resumed), trained, resumed without redoing anything, and checked against the runs they name; a failing cell does not
stop the others; one driver per study folder; `--address` without a Ray cluster is one line."""

import importlib.util
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from helpers import fake_run, mikt, runner, vpg_grid
from miktcli.cli.app import app
from miktcli.registry.cards import code_version
from miktcli.registry.runs import open_run

GRID = Path(__file__).resolve().parents[1] / "benchmarks" / "grids" / "tiny.toml"
SRC = Path(__file__).resolve().parents[1] / "src"
needs_ray = pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="ray is not installed")


@pytest.mark.slow
def test_study_runs_resumes_and_reports(registry, tmp_path):
    assert runner.invoke(app, ["teacher", "train", "hopper", "--steps", "2048", "--name", "tiny"]).exit_code == 0
    out = tmp_path / "results"
    r = runner.invoke(app, ["study", str(GRID), "--out", str(out)])
    assert r.exit_code == 0, r.output
    state = json.loads((out / "state.json").read_text())
    assert len(state) == 4 and len(set(state.values())) == 4
    table = (out / "results.md").read_text()
    assert "| mikt | 2 |" in table and "| vpg | 2 |" in table
    assert table.count(f"| {code_version()} from step 0 |") == 4  # which code trained each run
    assert (out / "curves-tiny-to-centipede-four.png").exists()
    assert (out / "weights-tiny-to-centipede-four.png").exists()
    # started again: nothing is redone
    r = runner.invoke(app, ["study", str(GRID), "--out", str(out)])
    assert r.exit_code == 0 and "start" not in r.output and "4/4" in r.output
    assert json.loads((out / "state.json").read_text()) == state


def test_a_cell_whose_run_id_now_names_another_run_is_an_error_not_a_result(registry, tmp_path):
    """state.json outliving its runs (a registry restored or reset) must not credit a cell with another run."""
    from miktcli.studies.grid import cell_key, load_grid
    from miktcli.studies.study import Study

    grid_file = tmp_path / "g.toml"
    grid_file.write_text('name = "g"\nsteps = 6144\nseeds = [0]\n[[pairs]]\nfrom = ["x"]\nto = "hopper"\n'
                         '[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    study = Study(load_grid(grid_file), tmp_path / "out", registry)
    other = fake_run(registry, "ant", "vpg", 0, [1, 2, 3], 5)  # a finished run of another cell
    study.state.remember(cell_key(*study.plan()[0]), other)
    for args in (["--report-only"], []):
        r = runner.invoke(app, ["study", str(grid_file), "--out", str(tmp_path / "out"), *args])
        assert r.exit_code == 1, r.output
        assert f"names {other}, but {other} is a transfer run of vpg on ant, seed 0" in r.output
    assert not (registry / "runs" / "run2").exists()  # nothing trained or created meanwhile


def test_a_run_recording_the_budget_as_asked_still_is_its_cell_and_a_wrong_budget_names_both(registry, tmp_path):
    """Runs made before budgets were rounded up to whole rollouts record the budget as asked (500,000, not
    501,760): they are still their cell's run. A run of another budget is refused, naming the rounded figure."""
    from miktcli.registry.runs import open_run
    from miktcli.studies.grid import cell_key, load_grid
    from miktcli.studies.study import Study

    grid_file = tmp_path / "g.toml"
    grid_file.write_text('name = "g"\nsteps = 5000\nseeds = [0]\n[[pairs]]\nfrom = ["x"]\nto = "hopper"\n'
                         '[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    study = Study(load_grid(grid_file), tmp_path / "out", registry)
    run_id = fake_run(registry, "hopper", "vpg", 0, [1, 2], 5)  # records 4,096 steps
    study.state.remember(cell_key(*study.plan()[0]), run_id)
    r = runner.invoke(app, ["study", str(grid_file), "--out", str(tmp_path / "out"), "--report-only"])
    assert r.exit_code == 1 and "trains 4,096 steps, the grid 5,000 (6,144 in whole rollouts of 2,048)" in r.output
    open_run(registry, run_id).save_card(total_steps=5000)  # the budget as asked, as mikt before 9519580 wrote it
    r = runner.invoke(app, ["study", str(grid_file), "--out", str(tmp_path / "out"), "--report-only"])
    assert r.exit_code == 0, r.output
    assert "| vpg | 1 |" in (tmp_path / "out" / "results.md").read_text()


def test_a_study_refuses_runs_its_registry_lacks_unless_told_to_retrain(registry, tmp_path):
    grid = vpg_grid(tmp_path, extra="eval_episodes = 1\n")
    out = tmp_path / "out"
    out.mkdir()
    state = {"->hopper|vpg|0": "run9"}
    (out / "state.json").write_text(json.dumps(state))
    r = mikt("study", grid, "--out", out, code=1)
    assert "names 1 run(s)" in r.output and "run9" in r.output
    assert f"that registry {registry} (from $MIKT_REGISTRY; no such folder) lacks" in r.output  # where it looked
    assert json.loads((out / "state.json").read_text()) == state  # untouched
    mikt("study", grid, "--out", out, "--retrain-missing")
    assert json.loads((out / "state.json").read_text()) == {"->hopper|vpg|0": "run1"}
    assert open_run(registry, "run1").card.status == "completed"


def test_a_corrupt_study_state_is_a_user_error(registry, tmp_path):
    grid = tmp_path / "g.toml"
    grid.write_text('name = "x"\nsteps = 2048\nseeds = [0]\n[[pairs]]\nfrom = ["a"]\nto = "hopper"\n'
                    '[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    out = tmp_path / "out"
    out.mkdir()
    (out / "state.json").write_text("{truncated")
    assert "damaged study state" in mikt("study", grid, "--out", out, code=1).output


def test_an_unwritable_study_folder_is_found_before_any_run_exists(registry, tmp_path, monkeypatch):
    import miktcli.registry.locks as locks

    grid = vpg_grid(tmp_path, extra="eval_episodes = 1\n")
    out, real_open = tmp_path / "out", locks.os.open

    def no_permission(path, *args):  # as in a folder this user cannot write (the tests may run as root)
        if os.path.dirname(path) == str(out):
            raise PermissionError(13, "Permission denied", str(path))
        return real_open(path, *args)

    monkeypatch.setattr(locks.os, "open", no_permission)
    assert "cannot write the study's results to" in mikt("study", grid, "--out", out, code=1).output
    assert not (registry / "runs").exists()


def test_the_ray_progress_overview_counts_cells_and_estimates_the_end():
    from miktcli.cli.study_progress import overview
    from miktcli.studies.executor import CellEvent

    cells = [CellEvent("a", "run1", 100, steps=100, state="completed"),
             CellEvent("b", "run2", 100, steps=40, steps_per_sec=5.0, state="training"),
             CellEvent("c", "run3", 100, steps=0, steps_per_sec=5.0, state="training"),
             CellEvent("d", "run4", 100, steps=0, state="queued"),
             CellEvent("e", "run5", 100, steps=10, state="failed")]
    # 3 finished before this driver started + run1; 60 + 100 + 100 steps left at 10 steps/s together
    assert overview(cells, finished_before=3) == (
        "4/8 cells completed, 2 training, 1 failed; 260 steps to go, about 0:00:26 at the current 10 steps/s")
    assert overview(cells[:1], finished_before=0) == "1/1 cells completed, 0 training; 0 steps to go"


# preparing cells ---------------------------------------------------------------------------------------------------

def study_of(registry, tmp_path, seeds):
    from miktcli.studies.grid import Grid
    from miktcli.studies.study import Study

    grid = Grid.model_validate({"name": "g", "steps": 2048, "seeds": list(range(seeds)),
                                "methods": [{"name": "vpg", "method": "vpg"}],
                                "pairs": [{"from": ["x"], "to": "hopper"}]})
    return Study(grid, tmp_path / "out", registry)


def test_preparing_many_cells_does_not_rewrite_state_json_per_cell(registry, tmp_path, monkeypatch):
    import miktcli.studies.state as state_module
    import miktcli.studies.study as study_module

    writes = []
    real_write = state_module.write_text_atomic
    monkeypatch.setattr(state_module, "write_text_atomic",
                        lambda path, text: (writes.append(path), real_write(path, text))[1])
    monkeypatch.setattr(study_module, "STATE_WRITE_EVERY_S", 3600.0)  # one write at the end, however slow here
    study = study_of(registry, tmp_path, 40)
    cells = study.prepare("test")
    state = json.loads(study.state.path.read_text())
    assert len(cells) == len(state) == 40 and [run.id for _, run in cells] == [f"run{i}" for i in range(1, 41)]
    assert writes.count(study.state.path) == 1


def test_a_preparation_stopped_part_way_names_the_runs_it_created(registry, tmp_path, monkeypatch):
    import miktcli.studies.study as study_module

    real_start, made = study_module.start_transfer, []

    def start_then_stop(*args, **kwargs):
        if len(made) == 5:
            raise KeyboardInterrupt  # Ctrl-C while the sixth cell's run is being made
        made.append(real_start(*args, **kwargs))
        return made[-1]

    monkeypatch.setattr(study_module, "STATE_WRITE_EVERY_S", 3600.0)
    monkeypatch.setattr(study_module, "start_transfer", start_then_stop)
    study = study_of(registry, tmp_path, 8)
    with pytest.raises(KeyboardInterrupt):
        study.prepare("test")
    assert sorted(json.loads(study.state.path.read_text()).values()) == sorted(run.id for run in made)
    monkeypatch.setattr(study_module, "start_transfer", real_start)
    cells = study_of(registry, tmp_path, 8).prepare("test")  # the next start reuses them, makes the rest
    assert [run.id for _, run in cells] == [f"run{i}" for i in range(1, 9)]


def test_run_ids_stay_in_order_when_another_process_made_runs_meanwhile(registry):
    from miktcli.registry.runs import runs_dir
    from miktcli.workflows.transfer import start_transfer

    def new():
        return start_transfer(registry, to="hopper", method="vpg", teacher_refs=[], steps=2048, seed=0,
                              command="test").id

    assert new() == "run1"
    (runs_dir(registry) / "run2").mkdir()  # as another process would
    (runs_dir(registry) / "run3").mkdir()
    assert new() == "run4"
    shutil.rmtree(runs_dir(registry) / "run4")
    (runs_dir(registry) / "run3").rmdir()
    (runs_dir(registry) / "run2").rmdir()
    assert new() == "run2"  # the runs this process made last are gone: the folder is listed again


def test_a_study_start_turns_never_trained_running_or_interrupted_cells_into_created(registry, tmp_path):
    from miktcli.registry.runs import open_run
    from miktcli.studies.grid import load_grid
    from miktcli.studies.study import Study

    grid_file = tmp_path / "g.toml"
    grid_file.write_text('name = "g"\nsteps = 6144\nseeds = [0, 1, 2]\n[[pairs]]\nfrom = ["x"]\nto = "hopper"\n'
                         '[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    study = Study(load_grid(grid_file), tmp_path / "out", registry)
    runs = [run for _, run in study.prepare("test")]
    runs[0].save_card(status="running")  # prepared before the `created` status
    runs[1].save_card(status="interrupted")  # marked by an older Ray driver that held it
    runs[2].save_card(status="interrupted", steps_done=2048)  # really trained: left alone
    study.prepare("test")
    assert [open_run(registry, r.id).card.status for r in runs] == ["created", "created", "interrupted"]


def test_a_prepared_run_that_never_trained_is_not_started_rather_than_stale(registry):
    from miktcli.registry.runs import open_run
    from miktcli.studies.grid import Grid, cell_key
    from miktcli.studies.study import Study
    from miktcli.workflows.transfer import start_transfer

    run = start_transfer(registry, to="centipede-four", method="vpg", teacher_refs=[], steps=2048, seed=0,
                         command="test")
    assert open_run(registry, run.id).status == "not started"
    assert "not started" in mikt("runs").output
    # a cell prepared by mikt 0.2 (marked running) becomes `created` when its study starts again
    open_run(registry, run.id).save_card(status="running")
    assert open_run(registry, run.id).status == "not started"
    grid = Grid.model_validate({"name": "g", "steps": 2048, "seeds": [0], "methods": [{"name": "vpg", "method": "vpg"}],
                                "pairs": [{"from": ["x"], "to": "centipede-four"}]})
    study = Study(grid, registry.parent / "out", registry)
    study.state.remember(cell_key(*study.plan()[0]), run.id)
    study.prepare("test")
    assert open_run(registry, run.id).card.status == "created"


# a failing cell ----------------------------------------------------------------------------------------------------

@pytest.fixture()
def seed_one_fails(monkeypatch):
    """Training of every seed-1 run raises in its first update (as a diverged or broken env would); call the
    returned function to let it train again."""
    from miktcli.engine.ppo import PPOTrainer

    original = PPOTrainer.update

    def update(self, batch):
        if self.seed == 1:
            raise RuntimeError("the simulation diverged")
        return original(self, batch)

    monkeypatch.setattr(PPOTrainer, "update", update)
    return lambda: monkeypatch.setattr(PPOTrainer, "update", original)


def failing_grid(tmp_path, steps=2048):
    return vpg_grid(tmp_path, steps, seeds=(0, 1, 2), extra="eval_episodes = 1\n")


@pytest.mark.slow
def test_a_serial_study_carries_on_past_a_failing_cell_and_reports_it(registry, tmp_path, seed_one_fails):
    grid, out = failing_grid(tmp_path), tmp_path / "out"
    r = runner.invoke(app, ["study", str(grid), "--out", str(out)])
    assert r.exit_code == 1, r.output
    state = json.loads((out / "state.json").read_text())
    assert [open_run(registry, state[f"->hopper|vpg|{s}"]).card.status for s in range(3)] == [
        "completed", "failed", "completed"]  # the cell after the failing one trained too
    failed = state["->hopper|vpg|1"]
    assert f"Error: ->hopper|vpg|1: {failed} failed: RuntimeError: the simulation diverged" in r.output
    assert "Error: 1 cell(s) failed; the others are reported" in r.output
    table = (out / "results.md").read_text()
    assert "| vpg | 2 |" in table  # the two completed seeds
    assert (f"**Failed cells** (their runs stopped with an error; running the study again retries them):\n\n"
            f"- ->hopper|vpg|1: {failed}: RuntimeError: the simulation diverged") in table

    # a rerun retries the failed cell (still failing here) and reports again; nothing else is redone
    r = runner.invoke(app, ["study", str(grid), "--out", str(out)])
    assert r.exit_code == 1 and f"->hopper|vpg|1: start {failed}" in r.output, r.output
    assert "1 cell(s) failed" in r.output and json.loads((out / "state.json").read_text()) == state

    seed_one_fails()  # the cause is gone: the rerun trains the failed cell and the report is whole
    r = runner.invoke(app, ["study", str(grid), "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert open_run(registry, failed).card.status == "completed"
    table = (out / "results.md").read_text()
    assert "| vpg | 3 |" in table and "Failed cells" not in table


def test_a_failing_cell_does_not_stop_the_cells_after_it_on_a_rerun(registry, tmp_path, seed_one_fails):
    """mikt 0.2 stopped at the first failing cell, and every rerun failed on it again: later cells never
    trained. Here only the cells up to the failing one exist when the rerun starts."""
    from miktcli.studies.executor import Driver
    from miktcli.studies.grid import load_grid
    from miktcli.studies.serial import SerialExecutor
    from miktcli.studies.study import Study

    study = Study(load_grid(failing_grid(tmp_path)), tmp_path / "out", registry)
    trained = []

    def train(cell_runs):
        (run,) = cell_runs  # one run a cell: the grid trains seeds alone
        trained.append(run.card.seed)
        if run.card.seed == 1:
            run.save_card(status="failed", error="ValueError: bad")
            raise ValueError("bad")
        run.save_card(status="completed", steps_done=run.card.total_steps)

    events = [(e.key, e.state) for e in Driver(study, SerialExecutor(train), "test").events()]
    assert trained == [0, 1, 2]
    assert events == [("->hopper|vpg|0", "training"), ("->hopper|vpg|0", "completed"),
                      ("->hopper|vpg|1", "training"), ("->hopper|vpg|1", "failed"),
                      ("->hopper|vpg|2", "training"), ("->hopper|vpg|2", "completed")]
    trained.clear()
    events = [(e.key, e.state) for e in Driver(study, SerialExecutor(train), "test").events()]
    assert trained == [1] and ("->hopper|vpg|1", "failed") in events and ("->hopper|vpg|2", "done") in events


def test_ctrl_c_in_a_serial_study_names_the_study_command(registry, tmp_path, ctrl_c_at_second_update):
    grid, out = failing_grid(tmp_path, steps=4096), tmp_path / "out"
    r = runner.invoke(app, ["study", str(grid), "--out", str(out)])
    assert r.exit_code == 1, r.output
    assert "Error: interrupted; run1 keeps its last complete checkpoint" in r.output
    assert "Hint: run the same command again to resume the study" in r.output
    assert "mikt transfer --resume" not in r.output
    assert open_run(registry, "run1").card.status == "interrupted"


# one driver per study folder ---------------------------------------------------------------------------------------

@pytest.mark.slow  # a second process drives the study
def test_a_second_driver_on_the_same_study_folder_is_refused(registry, tmp_path):
    grid, out = vpg_grid(tmp_path, steps=2048 * 40), tmp_path / "out"
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

    grid = load_grid(vpg_grid(tmp_path))
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

    grid = load_grid(vpg_grid(tmp_path))
    early, first = Study(grid, tmp_path / "out", registry), Study(grid, tmp_path / "out", registry)
    first.prepare("test")  # another driver prepared the cell since `early` read the folder
    assert [run.id for _, run in early.prepare("test")] == ["run1"]  # the same run, not a second one


# --address without a Ray cluster behind it: one line, before any cell is prepared (it used to hang, printing Ray's
# log lines, after creating every cell's run) -----------------------------------------------------------------

def ray_grid(tmp_path):
    return vpg_grid(tmp_path, seeds=(0, 1))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@needs_ray
def test_an_address_where_nothing_listens_is_one_line_before_any_cell_exists(registry, tmp_path):
    address = f"127.0.0.1:{free_port()}"
    r = runner.invoke(app, ["study", str(ray_grid(tmp_path)), "--out", str(tmp_path / "out"), "--address", address])
    assert r.exit_code == 1, r.output
    assert f"Error: no Ray cluster answers at {address}" in r.output
    assert "ray start --head" in r.output
    assert not (registry / "runs").exists() and not (tmp_path / "out" / "state.json").exists()


@needs_ray
def test_an_address_that_never_answers_times_out(registry, tmp_path, monkeypatch):
    import miktcli.studies.ray_executor as ray_executor

    monkeypatch.setattr(ray_executor, "RAY_CONNECT_TIMEOUT_S", 0.5)
    # TEST-NET-1 (RFC 5737): routed nowhere, so a connection waits until it times out (or fails at once
    # where the machine has no route at all); either way one line, no run
    r = runner.invoke(app, ["study", str(ray_grid(tmp_path)), "--out", str(tmp_path / "out"),
                            "--address", "192.0.2.1:6379"])
    assert r.exit_code == 1 and "Error: no Ray cluster answers at 192.0.2.1:6379" in r.output, r.output
    assert not (registry / "runs").exists()


@needs_ray
def test_auto_without_a_running_cluster_is_one_line(registry, tmp_path, monkeypatch):
    import ray._private.services as services

    def nothing_found(address):  # as on a machine where `ray start` never ran (other tests may run Ray here)
        raise ConnectionError("Could not find any running Ray instance. Please specify the one to connect to.")

    monkeypatch.setattr(services, "canonicalize_bootstrap_address_or_die", nothing_found)
    r = runner.invoke(app, ["study", str(ray_grid(tmp_path)), "--out", str(tmp_path / "out"), "--address", "auto"])
    assert r.exit_code == 1, r.output
    assert "Error: no Ray cluster answers at auto: Could not find any running Ray instance" in r.output
    assert not (registry / "runs").exists()


@needs_ray
def test_a_malformed_address_is_one_line(registry, tmp_path):
    r = runner.invoke(app, ["study", str(ray_grid(tmp_path)), "--out", str(tmp_path / "out"),
                            "--address", "not an address"])
    assert r.exit_code == 1 and "Error: --address 'not an address'" in r.output, r.output
    assert not (registry / "runs").exists()
