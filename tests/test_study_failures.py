"""A serial study carries on past a failing cell, writes its report and names the cell; a rerun retries the
failed cells and goes on (issue 37 F). Ctrl-C names the study command to resume, not `mikt transfer`."""

import json

import pytest
from typer.testing import CliRunner

from miktcli.cli.app import app
from miktcli.registry.runs import open_run

runner = CliRunner()


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


def write_grid(tmp_path, steps=2048):
    grid = tmp_path / "g.toml"
    grid.write_text(f'name = "g"\nsteps = {steps}\nseeds = [0, 1, 2]\neval_episodes = 1\n'
                    '[[pairs]]\nfrom = ["x"]\nto = "hopper"\n[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    return grid


def test_a_serial_study_carries_on_past_a_failing_cell_and_reports_it(registry, tmp_path, seed_one_fails):
    grid, out = write_grid(tmp_path), tmp_path / "out"
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
    from miktcli.studies.grid import load_grid
    from miktcli.studies.serial import run_serially
    from miktcli.studies.study import Study

    study = Study(load_grid(write_grid(tmp_path)), tmp_path / "out", registry)
    trained = []

    def train(cell_runs):
        (run,) = cell_runs  # one run a cell: the grid trains seeds alone
        trained.append(run.card.seed)
        if run.card.seed == 1:
            run.save_card(status="failed", error="ValueError: bad")
            raise ValueError("bad")
        run.save_card(status="completed", steps_done=run.card.total_steps)

    events = [(e.key, e.what) for e in run_serially(study, "test", train)]
    assert trained == [0, 1, 2]
    assert events == [("->hopper|vpg|0", "start"), ("->hopper|vpg|0", "finished"),
                      ("->hopper|vpg|1", "start"), ("->hopper|vpg|1", "failed"),
                      ("->hopper|vpg|2", "start"), ("->hopper|vpg|2", "finished")]
    trained.clear()
    events = [(e.key, e.what) for e in run_serially(study, "test", train)]
    assert trained == [1] and ("->hopper|vpg|1", "failed") in events and ("->hopper|vpg|2", "done") in events


def test_ctrl_c_in_a_serial_study_names_the_study_command(registry, tmp_path, ctrl_c_at_second_update):
    grid, out = write_grid(tmp_path, steps=4096), tmp_path / "out"
    r = runner.invoke(app, ["study", str(grid), "--out", str(out)])
    assert r.exit_code == 1, r.output
    assert "Error: interrupted; run1 keeps its last complete checkpoint" in r.output
    assert "Hint: run the same command again to resume the study" in r.output
    assert "mikt transfer --resume" not in r.output
    assert open_run(registry, "run1").card.status == "interrupted"
