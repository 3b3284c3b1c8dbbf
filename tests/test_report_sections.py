"""Report sections by name: a grid asks for one with `[[report]]` (here `reference`: a method beside another
implementation's published figures), its options are checked before any cell exists, and the section lands in
results.md and stays there when the report is written again."""

import json

from helpers import fake_run, mikt

GRID = ('name = "g"\nsteps = 8192\nseeds = [0, 1]\nmarks = [4096, 8192]\nrandom_returns = false\n'
        '[[pairs]]\nfrom = ["a", "b"]\nto = "hopper"\n'
        '[[methods]]\nname = "mikt"\nmethod = "mikt"\n[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
REFERENCE = ('estimator = "by hand"\nwindows = [[2048, 4096], [6144, 8192]]\n'
             '[[runs]]\nteachers = ["a", "b"]\nto = "hopper"\nreturns = [10, 50]\n')
ASK = '[[report]]\nsection = "reference"\nfile = "refs/theirs.toml"\nmethod = "mikt"\nlabel = "THEM"\n'


def grid_asking(tmp_path, ask=ASK):
    (tmp_path / "refs").mkdir(exist_ok=True)
    (tmp_path / "refs" / "theirs.toml").write_text(REFERENCE)
    grid = tmp_path / "g.toml"
    grid.write_text(GRID + ask)
    return grid


def test_a_reference_section_sets_the_method_beside_the_figures(registry, tmp_path, monkeypatch):
    grid, out = grid_asking(tmp_path), tmp_path / "out"
    rows = [{"episode_return_iter": r} for r in (10, 30, 50, 70)]
    cells = {"a+b>hopper|mikt|0": fake_run(registry, "hopper", "mikt", 0, [5, 10, 20, 40], 1, per_row=rows,
                                               teachers=("a", "b")),
             "a+b>hopper|mikt|1": fake_run(registry, "hopper", "mikt", 1, [5, 10, 20, 60], 1, per_row=rows,
                                               teachers=("a", "b")),
             "->hopper|vpg|0": fake_run(registry, "hopper", "vpg", 0, [1] * 4, 1),
             "->hopper|vpg|1": fake_run(registry, "hopper", "vpg", 1, [1] * 4, 1)}
    out.mkdir()
    (out / "state.json").write_text(json.dumps(cells))
    monkeypatch.chdir(registry)  # the reference file is found beside the grid, not in the working folder
    mikt("study", grid, "--out", out, "--report-only")
    text = (out / "results.md").read_text()
    assert "## `mikt` against THEM, pair by pair" in text
    # windows 2048-4096 (10, 30 → 20) and 6144-8192 (50, 70 → 60) on both seeds, beside 10 and 50
    assert "| a+b → hopper | 2 | 20 ± 0 | 10 | 60 ± 0 | 50 |" in text
    # the study's estimator at the marks (10, then 40 and 60 → 50 ± 14), +0 against 50 at the end: reached
    assert "| a+b → hopper | 2 | 10 ± 0 | 50 ± 14 | 50 | +0 | yes |" in text
    assert text.index("## `mikt` against THEM") > text.index("## a+b → hopper") and text.index("## Runs") > text.index(
        "## `mikt` against THEM")  # after the standard sections, before the table of runs
    mikt("study", grid, "--out", out, "--report-only")  # written again: the same report
    assert (out / "results.md").read_text() == text


def test_an_unknown_section_is_one_line_naming_the_sections(registry, tmp_path):
    grid = grid_asking(tmp_path, '[[report]]\nsection = "cat"\n')
    output = mikt("study", grid, "--out", tmp_path / "out", code=1).output
    assert "report[0]: unknown section 'cat'" in output and "reference" in output and "across-pairs" in output
    assert not (registry / "runs").exists()  # refused before any cell exists


def test_a_bad_option_is_one_line_naming_the_options(registry, tmp_path):
    output = mikt("study", grid_asking(tmp_path, ASK + "colour = 1\n"), "--out", tmp_path / "out", code=1).output
    assert "report[0] (reference)" in output and "file, method, label, fall" in output
    output = mikt("study", grid_asking(tmp_path, ASK.replace('"mikt"\nlabel', '"ppo"\nlabel')), code=1).output
    assert "the grid has no method 'ppo'" in output
    output = mikt("study", grid_asking(tmp_path, ASK.replace("theirs", "absent")), code=1).output
    assert "absent.toml: cannot be read" in output
    output = mikt("study", grid_asking(tmp_path, '[[report]]\nsection = "pairs"\n'), code=1).output
    assert "'pairs' is in every report already" in output
    assert not (registry / "runs").exists()


def test_a_reference_run_may_stand_for_a_target_of_another_name(tmp_path):
    """`targets = { OURS = THEIRS }`: the reference's run on THEIRS is set beside our pair on OURS (CAT's
    centipede-eight saw what centipede-eight-zero-contacts shows); its other runs stay as they were."""
    from miktcli.studies.reference import load_reference
    from miktcli.studies.sections import ReferenceOptions

    (tmp_path / "theirs.toml").write_text(REFERENCE)
    reference = load_reference(tmp_path / "theirs.toml").on_targets({"hopper-zero": "hopper", "ant-x": "ant"})
    assert reference.run_for("a+b", "hopper-zero").returns == [10, 50]
    assert reference.run_for("a+b", "hopper").returns == [10, 50] and reference.run_for("a+b", "ant-x") is None
    assert ReferenceOptions(file="f", method="m", targets={"hopper-zero": "hopper"}).targets == {
        "hopper-zero": "hopper"}
