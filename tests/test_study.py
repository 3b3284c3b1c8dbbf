import json
from pathlib import Path

from typer.testing import CliRunner

from miktcli.cli.app import app

runner = CliRunner()
GRID = Path(__file__).resolve().parents[1] / "benchmarks" / "grids" / "tiny.toml"


def test_study_runs_resumes_and_reports(registry, tmp_path):
    assert runner.invoke(app, ["teacher", "train", "hopper", "--steps", "2048", "--name", "tiny"]).exit_code == 0
    out = tmp_path / "results"
    r = runner.invoke(app, ["study", str(GRID), "--out", str(out)])
    assert r.exit_code == 0, r.output
    state = json.loads((out / "state.json").read_text())
    assert len(state) == 4 and len(set(state.values())) == 4
    table = (out / "results.md").read_text()
    assert "| mikt | 2 |" in table and "| vpg | 2 |" in table
    assert (out / "curves-tiny-to-centipede-four.png").exists()
    assert (out / "weights-tiny-to-centipede-four.png").exists()
    # started again: nothing is redone
    r = runner.invoke(app, ["study", str(GRID), "--out", str(out)])
    assert r.exit_code == 0 and "start" not in r.output and "4/4" in r.output
    assert json.loads((out / "state.json").read_text()) == state


def test_bad_grid_file(registry, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\nsteps = 10\nseeds = []\n')
    r = runner.invoke(app, ["study", str(bad)])
    assert r.exit_code == 1 and "field 'seeds'" in r.output
