"""A study pins its teacher references when it is first prepared (teachers.json), so that a later version of a
teacher does not change it; its report shows the versions its runs used."""

import json

import pytest

from helpers import runner
from miktcli.cli.app import app
from miktcli.registry.runs import open_run


@pytest.fixture()
def teacher_v1(registry):
    r = runner.invoke(app, ["teacher", "train", "hopper", "--steps", "2048", "--name", "tt"])
    assert r.exit_code == 0, r.output
    return registry


def publish_next_version(registry, name="tt"):
    """Another version of the teacher (the same weights: enough to tell versions apart)."""
    from miktcli.registry.teachers import load_teacher, publish_teacher

    t = load_teacher(registry, name)
    return publish_teacher(registry, t.card, t.policy).ref


def study_of(registry, out, seeds, ref="tt"):
    from miktcli.studies.grid import Grid
    from miktcli.studies.study import Study

    grid = Grid.model_validate({"name": "g", "steps": 2048, "seeds": seeds, "baseline": "mikt",
                                "methods": [{"name": "mikt", "method": "mikt"}],
                                "pairs": [{"from": [ref], "to": "hopper"}]})
    return Study(grid, out, registry)


def versions(registry, cells):
    return [f"{t.name}@v{t.version}" for _, run in cells for t in open_run(registry, run.id).card.teachers]


def test_a_study_keeps_the_teacher_version_it_was_first_prepared_with(teacher_v1, tmp_path):
    registry, out = teacher_v1, tmp_path / "out"
    assert versions(registry, study_of(registry, out, [0]).prepare("test")) == ["tt@v1"]
    assert json.loads((out / "teachers.json").read_text())["tt"]["ref"] == "tt@v1"
    assert publish_next_version(registry) == "tt@v2"  # e.g. `teacher import` under the same name
    # a seed added later trains with the version the study started with, not the new latest
    assert versions(registry, study_of(registry, out, [0, 1]).prepare("test")) == ["tt@v1", "tt@v1"]
    # and a new study of the same grid pins the latest at its start
    assert versions(registry, study_of(registry, tmp_path / "other", [0]).prepare("test")) == ["tt@v2"]


def test_the_report_shows_the_teacher_versions_and_a_mix(teacher_v1, tmp_path):
    from miktcli.workflows.transfer import start_transfer

    registry, out = teacher_v1, tmp_path / "out"
    study = study_of(registry, out, [0, 1])
    cells = study.prepare("test")
    sha = open_run(registry, cells[0][1].id).card.teachers[0].sha256
    study.report()
    assert f"Teachers: `tt` → tt@v1 (sha256 {sha[:12]})." in (out / "results.md").read_text()
    # a study prepared before pinning existed may mix versions: the report says which run used which
    publish_next_version(registry)
    other = start_transfer(registry, to="hopper", method="mikt", teacher_refs=["tt@v2"], steps=2048, seed=1,
                           command="test")
    study.state.remember("tt>hopper|mikt|1", other.id)
    study.report()
    assert (f"Teachers: `tt` → **mixed versions**: tt@v1 (sha256 {sha[:12]}; {cells[0][1].id}), "
            f"tt@v2 (sha256 {sha[:12]}; {other.id}).") in (out / "results.md").read_text()


def test_a_study_without_pins_pins_the_versions_its_runs_used(teacher_v1, tmp_path):
    """A study prepared by an older mikt (no teachers.json) keeps the version its first runs used."""
    registry, out = teacher_v1, tmp_path / "out"
    study_of(registry, out, [0]).prepare("test")
    (out / "teachers.json").unlink()
    publish_next_version(registry)
    assert versions(registry, study_of(registry, out, [0, 1]).prepare("test")) == ["tt@v1", "tt@v1"]
    assert json.loads((out / "teachers.json").read_text())["tt"]["ref"] == "tt@v1"


def test_a_pinned_teacher_that_is_another_file_here_is_refused(teacher_v1, tmp_path):
    registry, out = teacher_v1, tmp_path / "out"
    study_of(registry, out, [0]).prepare("test")
    pins = json.loads((out / "teachers.json").read_text())
    pins["tt"]["sha256"] = "0" * 64  # as on another machine whose tt@v1 is another teacher
    (out / "teachers.json").write_text(json.dumps(pins))
    r = runner.invoke(app, ["study", str(write_grid(tmp_path, seeds="[0, 1]")), "--out", str(out)])
    assert r.exit_code == 1, r.output
    assert "pinned `tt` to tt@v1 (sha256 000000000000), but tt@v1 in" in r.output
    assert not (registry / "runs" / "run3").exists()  # run1: the teacher's, run2: seed 0's cell


def test_a_damaged_pin_file_is_one_line(teacher_v1, tmp_path):
    registry, out = teacher_v1, tmp_path / "out"
    out.mkdir()
    (out / "teachers.json").write_text('{"tt": "tt@v1"}')
    r = runner.invoke(app, ["study", str(write_grid(tmp_path)), "--out", str(out)])
    assert r.exit_code == 1 and f"{out / 'teachers.json'}: damaged teacher pins" in r.output, r.output
    assert not (registry / "runs" / "run2").exists()


def write_grid(tmp_path, seeds="[0]"):
    grid = tmp_path / "g.toml"
    grid.write_text(f'name = "g"\nsteps = 2048\nseeds = {seeds}\neval_episodes = 1\nbaseline = "mikt"\n'
                    '[[pairs]]\nfrom = ["tt"]\nto = "hopper"\n[[methods]]\nname = "mikt"\nmethod = "mikt"\n')
    return grid


def test_the_cli_says_what_it_pinned(teacher_v1, tmp_path):
    r = runner.invoke(app, ["study", str(write_grid(tmp_path)), "--out", str(tmp_path / "out")])
    assert r.exit_code == 0, r.output
    assert "study: `tt` pinned to tt@v1 (teachers.json); a later version of tt does not change this study" \
        in r.output
