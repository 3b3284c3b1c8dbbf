"""The study executors: the serial one and the Ray one implement one protocol (studies.executor.Executor), and
the one driver trains a small grid through either to the same end: every cell completed, once, and reported."""

import json

import pytest

from helpers import vpg_grid
from miktcli.registry.runs import open_run


def executors(registry):
    from miktcli.cli.training import train_cells
    from miktcli.studies.ray_executor import RayExecutor
    from miktcli.studies.serial import SerialExecutor

    return {"serial": SerialExecutor(lambda runs: train_cells(runs, registry, 1)),
            "ray": RayExecutor(workers=1, address=None, eval_episodes=1, chunk_iterations=1)}


def test_both_executors_implement_the_protocol(tmp_path):
    from miktcli.studies.executor import Executor

    for name, executor in executors(tmp_path / "registry").items():
        assert isinstance(executor, Executor), name


def test_both_executors_train_seeds_together(tmp_path):
    from miktcli.studies.grid import load_grid

    grid = load_grid(vpg_grid(tmp_path, seeds=(0, 1), extra="seeds_together = true\n"))
    assert {name: e.refuses(grid) for name, e in executors(tmp_path / "registry").items()} == {
        "serial": None, "ray": None}


def drive(registry, tmp_path, name):
    from miktcli.studies.executor import Driver
    from miktcli.studies.grid import load_grid
    from miktcli.studies.study import Study

    study = Study(load_grid(vpg_grid(tmp_path, seeds=(0, 1))), tmp_path / "out", registry)
    driver = Driver(study, executors(registry)[name], "test")
    return study, driver, [(e.key, e.state) for e in driver.events()]


def check_one_run_of_the_grid(registry, tmp_path, name):
    study, driver, events = drive(registry, tmp_path, name)
    cells = ["->hopper|vpg|0", "->hopper|vpg|1"]
    assert sorted(key for key, state in events if state == "completed") == cells, events
    assert not driver.failed and driver.report.path == study.out_dir / "results.md"
    state = json.loads((study.out_dir / "state.json").read_text())
    assert all(open_run(registry, state[cell]).card.status == "completed" for cell in cells)
    assert "| vpg | 2 |" in driver.report.path.read_text()
    _, _, again = drive(registry, tmp_path, name)  # a second session trains nothing: each cell is done
    assert sorted(again) == [(cell, "done") for cell in cells]


def test_the_serial_executor_trains_a_grid_through_the_driver(registry, tmp_path):
    check_one_run_of_the_grid(registry, tmp_path, "serial")


@pytest.mark.slow
def test_the_ray_executor_trains_a_grid_through_the_driver(registry, tmp_path):
    pytest.importorskip("ray")
    check_one_run_of_the_grid(registry, tmp_path, "ray")


@pytest.mark.slow
def test_ray_trains_a_cell_s_seeds_together_in_chunks_as_the_serial_executor_does(registry, tmp_path):
    """One task a cell (its two seeds as one batched problem), three chunks of one iteration each, every chunk
    resumed from the checkpoints handed back: the same metrics as the serial executor's one go, to the bit."""
    pytest.importorskip("ray")
    from miktcli.studies.executor import Driver
    from miktcli.studies.grid import load_grid
    from miktcli.studies.study import Study

    metrics = {}
    for name in ("serial", "ray"):
        folder = tmp_path / name
        folder.mkdir()
        grid = load_grid(vpg_grid(folder, steps=3 * 2048, seeds=(0, 1), extra="seeds_together = true\n"))
        study = Study(grid, folder / "out", registry)
        events = list(Driver(study, executors(registry)[name], "test").events())
        assert sorted(e.key for e in events if e.state == "completed") == ["->hopper|vpg|0", "->hopper|vpg|1"]
        state = json.loads((folder / "out" / "state.json").read_text())
        runs = [open_run(registry, state[f"->hopper|vpg|{seed}"]) for seed in (0, 1)]
        assert all(run.card.seeds_together == [r.id for r in runs] for run in runs)  # one group, both named
        metrics[name] = [[{k: v for k, v in json.loads(line).items() if not k.startswith(("time_", "steps_per"))}
                          for line in (run.path / "metrics.jsonl").read_text().splitlines()] for run in runs]
    assert [len(rows) for rows in metrics["ray"]] == [3, 3]
    assert metrics["ray"] == metrics["serial"]
