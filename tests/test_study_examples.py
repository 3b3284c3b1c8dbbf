"""The example grids shipped inside the package: listed, run by name from an empty folder (as from a wheel,
where benchmarks/ is absent), copied out to edit; each one names only what ships with mikt."""

import json
import tomllib
from pathlib import Path

import pytest

from helpers import mikt

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture()
def empty_folder(tmp_path, monkeypatch):
    """A user's empty working folder: no MIKT_REGISTRY, no spec folder, the packaged teachers visible."""
    folder = tmp_path / "work"
    folder.mkdir()
    monkeypatch.chdir(folder)
    monkeypatch.delenv("MIKT_REGISTRY", raising=False)
    monkeypatch.delenv("MIKT_ENVSPECS", raising=False)
    monkeypatch.setenv("MIKT_PACKAGED_TEACHERS", "1")
    return folder


def test_examples_are_listed_with_a_description():
    listed = json.loads(mikt("study", "examples", "--json").stdout)
    names = [e["name"] for e in listed]
    assert {"tiny", "hopper-to-four", "four-to-eight"} <= set(names) and names == sorted(names)
    assert all(e["description"] and Path(e["path"]).is_file() for e in listed)
    table = mikt("study", "examples").stdout
    assert "tiny" in table and "Seconds" in table


def test_every_example_names_only_what_ships_with_mikt(monkeypatch):
    from miktcli.envs.spec import spec_names
    from miktcli.examples import examples
    from miktcli.registry.packaged import packaged_teachers
    from miktcli.studies.grid import load_grid

    monkeypatch.delenv("MIKT_ENVSPECS", raising=False)
    monkeypatch.setenv("MIKT_PACKAGED_TEACHERS", "1")
    shipped_teachers, shipped_envs = set(packaged_teachers()), set(spec_names())
    for e in examples():
        grid = load_grid(e.path)
        assert grid.name == e.name  # its default results folder is ./studies/NAME
        assert {t.split("@")[0] for p in grid.pairs for t in p.teachers} <= shipped_teachers, e.name
        assert {p.to for p in grid.pairs} <= shipped_envs, e.name
        assert not grid.report, f"{e.name}: a report section may name a file beside the grid, absent from a wheel"


def test_the_four_to_eight_example_is_the_benchmark_grid():
    from miktcli.examples import example

    shipped = tomllib.loads(example("four-to-eight").path.read_text())
    assert shipped == tomllib.loads((ROOT / "benchmarks" / "grids" / "four-to-eight.toml").read_text())


@pytest.mark.slow
def test_the_tiny_example_runs_from_an_empty_folder(empty_folder):
    r = mikt("study", "--example", "tiny")
    assert r.stdout.strip() == "studies/tiny/results.md"
    assert (empty_folder / "studies" / "tiny" / "results.md").is_file()
    assert sorted(p.name for p in (empty_folder / "registry" / "runs").iterdir()) == ["run1", "run2"]
    card = json.loads((empty_folder / "registry" / "runs" / "run1" / "run.json").read_text())
    assert card["status"] == "completed" and card["teachers"][0]["name"] == "hopper"
    # `mikt study run --example` is the same study: finished, so only its report
    assert "completed" not in mikt("study", "run", "--example", "tiny", "--report-only").output


def test_an_unknown_example_is_one_line_naming_the_known_ones(empty_folder):
    r = mikt("study", "--example", "nope", code=1)
    assert "unknown example grid 'nope'; known: four-to-eight, hopper-to-four, tiny" in r.output
    assert "unknown example grid 'nope'" in mikt("study", "examples", "--copy", "nope", code=1).output
    assert not (empty_folder / "studies").exists()


def test_a_grid_file_or_an_example_exactly(empty_folder):
    assert "give a grid file or --example NAME" in mikt("study", "run", "--out", "x", code=2).output
    assert "give a grid file or --example NAME" in mikt("study", "g.toml", "--example", "tiny", code=2).output


def test_an_example_copied_out_runs_as_a_file_and_is_never_overwritten(empty_folder):
    from miktcli.examples import example

    assert mikt("study", "examples", "--copy", "tiny").stdout.strip() == "tiny.toml"
    assert (empty_folder / "tiny.toml").read_text() == example("tiny").path.read_text()
    (empty_folder / "tiny.toml").write_text("# my edit\n")
    r = mikt("study", "examples", "--copy", "tiny", code=1)
    assert "tiny.toml already exists; not overwriting it" in r.output
    assert (empty_folder / "tiny.toml").read_text() == "# my edit\n"
    # a folder, existing or named with a trailing slash, takes NAME.toml
    assert mikt("study", "examples", "--copy", "four-to-eight", "--to", "grids/").stdout.strip() == \
        "grids/four-to-eight.toml"
    assert json.loads(mikt("study", "examples", "--copy", "tiny", "--to", "grids", "--json").stdout)["path"] == \
        "grids/tiny.toml"
    assert "not a .toml path" in mikt("study", "examples", "--copy", "tiny", "--to", "grid.txt", code=1).output
    assert "applies only with --copy" in mikt("study", "examples", "--to", "x.toml", code=2).output
