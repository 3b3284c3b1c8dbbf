"""Grid sizes are bounded (MAX_GRID_CELLS, MAX_GRID_FILE_BYTES), validated in linear time, and a study's
cells are prepared without rewriting state.json once per cell (issue 37 D, the study part)."""

import json
import shutil

import pytest
from typer.testing import CliRunner

from miktcli.cli.app import app

runner = CliRunner()
VPG = '[[pairs]]\nfrom = ["x"]\nto = "hopper"\n[[methods]]\nname = "vpg"\nmethod = "vpg"\n'


def test_a_grid_beyond_the_cell_limit_is_one_line(registry, tmp_path):
    from miktcli.studies.grid import MAX_GRID_CELLS

    seeds = MAX_GRID_CELLS * 2  # validation of 20,000 seeds took ~14 s (quadratic), then every cell was made
    grid = tmp_path / "g.toml"
    grid.write_text(f'name = "g"\nsteps = 2048\nseeds = [{", ".join(map(str, range(seeds)))}]\n' + VPG)
    r = runner.invoke(app, ["study", str(grid), "--out", str(tmp_path / "out")])
    assert r.exit_code == 1, r.output
    assert (f"20,000 cells (1 pair(s) × 1 method(s) × 20,000 seed(s)); a grid holds at most {MAX_GRID_CELLS:,}"
            in r.output)
    assert not (registry / "runs").exists() and not (tmp_path / "out").exists()


def test_duplicates_are_still_named_in_a_large_grid(tmp_path):
    from miktcli.errors import MiktError
    from miktcli.studies.grid import MAX_GRID_CELLS, load_grid

    grid = tmp_path / "g.toml"
    seeds = [*range(MAX_GRID_CELLS - 1), 7]
    grid.write_text(f'name = "g"\nsteps = 2048\nseeds = [{", ".join(map(str, seeds))}]\n' + VPG)
    with pytest.raises(MiktError, match="duplicate seed: 7$"):
        load_grid(grid)


def test_a_grid_file_beyond_the_size_limit_is_refused_without_reading_it_whole(tmp_path):
    from miktcli.errors import MiktError
    from miktcli.studies.grid import MAX_GRID_FILE_BYTES, load_grid

    grid = tmp_path / "g.toml"
    grid.write_text('name = "g"\nsteps = 2048\nseeds = [0]\n' + VPG + "#" * MAX_GRID_FILE_BYTES + "\n")
    with pytest.raises(MiktError, match=f"a grid file holds at most {MAX_GRID_FILE_BYTES:,} bytes"):
        load_grid(grid)
    with pytest.raises(MiktError, match="a device, not a regular file"):
        load_grid("/dev/zero")  # endless: refused without reading


def study_of(registry, tmp_path, seeds):
    from miktcli.studies.grid import Grid
    from miktcli.studies.study import Study

    grid = Grid.model_validate({"name": "g", "steps": 2048, "seeds": list(range(seeds)),
                                "methods": [{"name": "vpg", "method": "vpg"}],
                                "pairs": [{"from": ["x"], "to": "hopper"}]})
    return Study(grid, tmp_path / "out", registry)


def test_preparing_many_cells_does_not_rewrite_state_json_per_cell(registry, tmp_path, monkeypatch):
    import miktcli.studies.study as study_module

    writes = []
    real_write = study_module.write_text_atomic
    monkeypatch.setattr(study_module, "write_text_atomic",
                        lambda path, text: (writes.append(path), real_write(path, text))[1])
    monkeypatch.setattr(study_module, "STATE_WRITE_EVERY_S", 3600.0)  # one write at the end, however slow here
    study = study_of(registry, tmp_path, 40)
    cells = study.prepare("test")
    state = json.loads(study.state_path.read_text())
    assert len(cells) == len(state) == 40 and [run.id for _, run in cells] == [f"run{i}" for i in range(1, 41)]
    assert writes.count(study.state_path) == 1


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
    assert sorted(json.loads(study.state_path.read_text()).values()) == sorted(run.id for run in made)
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
