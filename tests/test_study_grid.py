"""Study grid files: what a grid may hold (sizes bounded and validated in linear time, no duplicates, no names
that collide or escape the study folder, options that validate), every committed grid loads, and a grid's unknown
teacher or target is found before any cell trains."""

from pathlib import Path

import pytest

from helpers import mikt, runner
from miktcli.cli.app import app

GRIDS = Path(__file__).resolve().parents[1] / "benchmarks" / "grids"
VPG = '[[pairs]]\nfrom = ["x"]\nto = "hopper"\n[[methods]]\nname = "vpg"\nmethod = "vpg"\n'


def test_bad_grid_file(registry, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\nsteps = 10\nseeds = []\n')
    r = runner.invoke(app, ["study", str(bad)])
    assert r.exit_code == 1 and "field 'seeds'" in r.output


def test_grid_files_that_are_binary_or_evaluate_nothing_are_refused(registry, tmp_path):
    grid = tmp_path / "g.toml"
    grid.write_bytes(b"\xff\xfe\x00\x01")
    assert "not a UTF-8 text file" in mikt("study", grid, code=1).output
    grid.write_text(EPISODES_GRID.format(episodes=0))
    assert "eval_episodes" in mikt("study", grid, code=1).output


def test_grids_with_duplicate_methods_or_pairs_are_refused(tmp_path):
    from miktcli.errors import MiktError
    from miktcli.studies.grid import load_grid

    base = 'name = "x"\nsteps = 2048\nseeds = [0]\n'
    pair = '[[pairs]]\nfrom = ["a"]\nto = "hopper"\n'
    vpg = '[[methods]]\nname = "vpg"\nmethod = "vpg"\n'
    for body, message in ((pair + vpg + vpg, "duplicate method name: vpg"),
                          (pair + pair + vpg, "duplicate pair: a → hopper")):
        (tmp_path / "g.toml").write_text(base + body)
        try:
            load_grid(tmp_path / "g.toml")
        except MiktError as err:
            assert message in str(err)
        else:
            raise AssertionError("accepted")


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


EPISODES_GRID = ('name = "x"\nsteps = 2048\nseeds = [0]\neval_episodes = {episodes}\n[[pairs]]\nfrom = ["a"]\n'
                 'to = "hopper"\n[[methods]]\nname = "vpg"\nmethod = "vpg"\n')


def grid_error(tmp_path, body):
    from miktcli.errors import MiktError
    from miktcli.studies.grid import load_grid

    (tmp_path / "g.toml").write_text(body)
    with pytest.raises(MiktError) as caught:
        load_grid(tmp_path / "g.toml")
    return str(caught.value)


PAIR = '[[pairs]]\nfrom = ["{t}"]\nto = "hopper"\nlabel = "{label}"\n'
NAMED = '[[methods]]\nname = "{name}"\nmethod = "vpg"\n'


@pytest.mark.parametrize(("head", "body", "message"), [
    ('name = "x"\nsteps = 2048\nseeds = [0]\n', PAIR.format(t="a", label="same") + PAIR.format(t="b", label="same")
     + NAMED.format(name="vpg"), "duplicate pair label: same"),
    ('name = "x"\nsteps = 2048\nseeds = [0]\nbaseline = "m x"\n', PAIR.format(t="a", label="p")
     + NAMED.format(name="m x") + NAMED.format(name="m-x"), "duplicate method name (as a file name): m-x"),
    ('name = "x"\nsteps = 4096\nseeds = [0]\nmarks = [2048, 99999]\n', PAIR.format(t="a", label="p")
     + NAMED.format(name="vpg"), "mark 99,999 is outside"),
    ('name = "../../escaped"\nsteps = 2048\nseeds = [0]\n', PAIR.format(t="a", label="p") + NAMED.format(name="vpg"),
     "field 'name'"),
    ('name = "x"\nsteps = 2048\nseeds = [-1]\n', PAIR.format(t="a", label="p") + NAMED.format(name="vpg"),
     "field 'seeds.0'"),
])
def test_grids_whose_reports_would_collide_or_mislead_are_refused(tmp_path, head, body, message):
    assert message in grid_error(tmp_path, head + body)


def test_any_method_without_teachers_is_shared_per_target(monkeypatch, registry, tmp_path):
    import dataclasses

    from miktcli.methods import METHODS
    from miktcli.methods.vpg import METHOD as VPG
    from miktcli.studies.grid import Grid, cell_key
    from miktcli.studies.study import Study

    # a new from-scratch method is known by its Method record (max_teachers = 0), not by its name
    monkeypatch.setitem(METHODS, "scratch", dataclasses.replace(VPG, name="scratch"))
    grid = Grid.model_validate({"name": "g", "steps": 2048, "seeds": [0], "baseline": "s",
                                "methods": [{"name": "s", "method": "scratch"}, {"name": "m", "method": "mlpp"}],
                                "pairs": [{"from": ["a"], "to": "hopper"}, {"from": ["b"], "to": "hopper"}]})
    assert [cell_key(*cell) for cell in Study(grid, tmp_path / "out", registry).distinct_cells()] == [
        "->hopper|s|0", "a>hopper|m|0", "b>hopper|m|0"]


def test_unknown_teacher_is_found_before_any_cell_trains(registry, tmp_path):
    grid = tmp_path / "g.toml"
    grid.write_text('name = "x"\nsteps = 2048\nseeds = [0]\n[[pairs]]\nfrom = ["ghost"]\nto = "hopper"\n'
                    '[[methods]]\nname = "vpg"\nmethod = "vpg"\n[[methods]]\nname = "mikt"\nmethod = "mikt"\n')
    r = runner.invoke(app, ["study", str(grid), "--out", str(tmp_path / "o")])
    assert r.exit_code == 1 and "unknown teacher 'ghost'" in r.output
    assert not (registry / "runs").exists()


def test_an_unknown_target_env_is_an_error_even_for_report_only(registry, tmp_path):
    """A misspelt target trains nothing; reporting its pair as merely unfinished would hide the typo."""
    grid = tmp_path / "g.toml"
    grid.write_text('name = "x"\nsteps = 2048\nseeds = [0]\n[[pairs]]\nfrom = ["t"]\nto = "centipede-nine"\n'
                    '[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    for args in (["--report-only"], []):
        r = runner.invoke(app, ["study", str(grid), "--out", str(tmp_path / "o"), *args])
        assert r.exit_code == 1, r.output
        assert "pair t → centipede-nine: unknown environment 'centipede-nine'" in r.output
    assert not (tmp_path / "o").exists() and not (registry / "runs").exists()


def test_every_committed_grid_loads_and_its_options_validate():
    from miktcli.methods import get_method
    from miktcli.studies.grid import load_grid
    from miktcli.studies.study import Study

    grids = sorted(GRIDS.glob("*.toml"))
    assert any(g.name == "multi-screen.toml" for g in grids)
    for path in grids:
        grid = load_grid(path)
        for method in grid.methods:  # what the study does before the first cell: an unknown option fails here
            get_method(method.method).parse_options(method.options)
        if grid.name == "multi-screen":
            assert len(Study(grid, Path("/nonexistent"), Path("/nonexistent")).distinct_cells()) <= 16


def test_a_pair_may_train_its_own_seeds_and_runs_from_scratch_keep_the_grid_s(registry, tmp_path):
    """`seeds` on a pair (a one-teacher comparison needs fewer seeds than the pairs it is set beside): the
    methods with teachers train those, a run from scratch is the target's and keeps the grid's seeds."""
    from miktcli.errors import MiktError
    from miktcli.studies.grid import Grid, cell_key, load_grid
    from miktcli.studies.study import Study

    grid = Grid.model_validate({"name": "g", "steps": 2048, "seeds": [0, 1, 2],
                                "methods": [{"name": "vpg", "method": "vpg"}, {"name": "m", "method": "mlpp"}],
                                "pairs": [{"from": ["a", "b"], "to": "hopper"},
                                          {"from": ["a"], "to": "hopper", "seeds": [0]}]})
    assert [cell_key(*cell) for cell in Study(grid, tmp_path / "out", registry).distinct_cells()] == [
        "->hopper|vpg|0", "->hopper|vpg|1", "->hopper|vpg|2", "a+b>hopper|m|0", "a+b>hopper|m|1",
        "a+b>hopper|m|2", "a>hopper|m|0"]
    one = grid.pairs[1]
    assert grid.seeds_of(one, grid.methods[1]) == [0] and grid.seeds_of(one, grid.methods[0]) == [0, 1, 2]
    path = tmp_path / "g.toml"
    for seeds, message in (("[1, 1]", "duplicate seed of pair a → hopper: 1"), ("[]", "seeds")):
        path.write_text(f'name = "g"\nsteps = 2048\nseeds = [0]\n[[pairs]]\nfrom = ["a"]\nto = "hopper"\n'
                        f'seeds = {seeds}\n[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
        with pytest.raises(MiktError, match=message):
            load_grid(path)
