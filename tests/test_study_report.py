"""Every study report carries the numbers across pairs (issue 34): scores normalised between the random policy and
the baseline, the IQM and P(X > Y) with stratified bootstrap intervals, performance profiles; the random returns
are measured once per target into the study folder's random-returns.json, and the section says why it is
missing where it cannot be built."""

import json

import pytest
from typer.testing import CliRunner

from helpers import fake_run
from miktcli.cli.app import app

runner = CliRunner()
RANDOM = {"hopper": 0.0, "ant": 5.0}
GRID = ('name = "agg"\nsteps = 6144\nseeds = [0, 1]\nbaseline = "{baseline}"\n{extra}'
        '[[pairs]]\nfrom = ["four"]\nto = "hopper"\n[[pairs]]\nfrom = ["four"]\nto = "ant"\n'
        '[[methods]]\nname = "mikt"\nmethod = "mikt"\n[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
# final returns: vpg hopper 10, 30 (R_vpg 20), ant 20, 40 (R_vpg 30); mikt twice to thrice that
FINALS = {"->hopper|vpg|0": 10, "->hopper|vpg|1": 30, "->ant|vpg|0": 20, "->ant|vpg|1": 40,
          "four>hopper|mikt|0": 40, "four>hopper|mikt|1": 60, "four>ant|mikt|0": 50, "four>ant|mikt|1": 70}


@pytest.fixture()
def measured(monkeypatch):
    """The random-policy measurement stood in for: the targets it was asked for, in order."""
    calls = []

    def measure(target, episodes, seed):
        calls.append((target, episodes, seed))
        return {"episodes": episodes, "seed": seed, "return_mean": RANDOM[target], "return_std": 0.0,
                "length_mean": 20.0, "returns": [RANDOM[target]] * episodes}

    monkeypatch.setattr("miktcli.studies.random_cache.random_returns", measure)
    return calls


def study_with(registry, tmp_path, cells=FINALS, extra="", baseline="vpg"):
    from miktcli.studies.grid import load_grid
    from miktcli.studies.study import Study

    grid_file = tmp_path / "agg.toml"
    grid_file.write_text(GRID.format(extra=extra, baseline=baseline))
    study = Study(load_grid(grid_file), tmp_path / "out", registry)
    for key, final in cells.items():
        target, method, seed = key.split(">")[1].split("|")
        teachers = [] if method == "vpg" else ["four"]
        study._remember(key, fake_run(registry, target, method, int(seed), [0, 0, final], 1, teachers=teachers))
    return study, grid_file


def section(out):
    text = (out / "results.md").read_text()
    return text.split("## Across pairs")[1].split("\n## ")[0]


def test_the_report_normalises_by_random_and_the_baseline_and_caches_the_random_returns(registry, tmp_path,
                                                                                       measured):
    study, grid_file = study_with(registry, tmp_path)
    study.report()
    out = tmp_path / "out"
    text = section(out)
    final = text.split("### Final return")[1].split("### Mean over training")[0]
    # normalised: hopper mikt 2, 3, vpg 0.5, 1.5; ant (random 5) mikt 1.8, 2.6, vpg 0.6, 1.4. IQM of the four
    # pooled: the middle two (2, 2.6 → 2.3; 0.6, 1.4 → 1); mikt beats every vpg run
    assert "| mikt | 4 | 2 | 2.30 [" in final and "| vpg | 4 | 2 | 1.00 [" in final
    assert "| mikt vs vpg | 1.00 [1.00, 1.00] | 2 |" in final
    assert "| four → ant | 2.20 | 1.00 |" in final  # two runs: nothing trimmed
    assert "| ant | 5.0 | 30 | 2 |" in text and "| hopper | 0.0 | 20 | 2 |" in text
    assert "random-returns.json in this folder" in text and "Left out" not in text
    assert "![performance profiles](aggregate-profile.png)" in text
    assert (out / "aggregate-profile.png").read_bytes()[:4] == b"\x89PNG"
    # the same numbers in summary.json
    across = json.loads((out / "summary.json").read_text())["across_pairs"]
    assert across["missing"] is None and across["notes"] == []
    mikt = across["measures"]["final return"]["methods"]["mikt"]
    assert (mikt["runs"], mikt["pairs"]) == (4, 2) and mikt["iqm"]["value"] == pytest.approx(2.3)
    assert mikt["iqm"]["low"] <= 2.3 <= mikt["iqm"]["high"]
    assert across["measures"]["final return"]["probability_of_improvement"] == [
        {"x": "mikt", "y": "vpg", "estimate": {"value": 1.0, "low": 1.0, "high": 1.0}, "pairs": 2}]
    assert across["measures"]["final return"]["per_pair"]["four → ant"] == {"mikt": pytest.approx(2.2),
                                                                             "vpg": pytest.approx(1.0)}
    # mean over training (the curves' means): ant vpg 20/3, 40/3 → R_vpg 10, so mikt's 50/3 is (50/3 − 5) / 5
    assert across["measures"]["mean over training"]["per_pair"]["four → ant"]["mikt"] == pytest.approx(3.0)
    assert [n["task"] for n in across["normalisation"]] == ["hopper", "ant"]
    assert across["normalisation"][1] == {"task": "ant", "random": 5.0, "runs": 2,
                                          "reference": {"final return": 30.0, "mean over training": 10.0}}
    assert across["profiles"] == {"figure": "aggregate-profile.png", "measure": "final return",
                                  "methods": ["mikt", "vpg"]}
    # each target measured once, by the committed protocol, and cached with its provenance
    assert measured == [("hopper", 100, 0), ("ant", 100, 0)]
    cache = json.loads((out / "random-returns.json").read_text())
    assert cache["policy"] == "uniform over the action box" and set(cache["targets"]) == {"hopper", "ant"}
    assert cache["targets"]["ant"]["return_mean"] == 5.0 and cache["targets"]["ant"]["code_version"]
    assert "agg" in cache["targets"]["ant"]["measured_by"]
    # reported again, through the CLI: read from the cache, not measured again, the same numbers
    r = runner.invoke(app, ["study", str(grid_file), "--out", str(out), "--report-only"])
    assert r.exit_code == 0, r.output
    assert len(measured) == 2 and section(out) == text


def test_a_seeded_cache_is_used_as_it_is_and_only_missing_targets_are_measured(registry, tmp_path, measured):
    study, _ = study_with(registry, tmp_path)
    out = tmp_path / "out"
    seeded = {"policy": "uniform over the action box", "code_version": "9fc0f75", "command": "seeded",
              "targets": {"ant": {"episodes": 100, "seed": 0, "return_mean": 5.0, "return_std": 1.0,
                                  "length_mean": 30.0, "returns": [5.0]}}}
    (out / "random-returns.json").write_text(json.dumps(seeded))
    study.report()
    assert measured == [("hopper", 100, 0)]
    cache = json.loads((out / "random-returns.json").read_text())
    assert cache["targets"]["ant"] == seeded["targets"]["ant"]  # left as it was
    assert (cache["code_version"], cache["command"]) == ("9fc0f75", "seeded")
    assert "| mikt | 4 | 2 | 2.30 [" in section(out)


def test_random_returns_false_leaves_the_numbers_out_and_says_so(registry, tmp_path, measured):
    study, _ = study_with(registry, tmp_path, extra="random_returns = false\n")
    study.report()
    out = tmp_path / "out"
    assert "No aggregates across pairs: the grid says `random_returns = false`." in section(out)
    assert measured == [] and not (out / "random-returns.json").exists()
    assert not (out / "aggregate-profile.png").exists()
    across = json.loads((out / "summary.json").read_text())["across_pairs"]
    assert across["missing"] == "the grid says `random_returns = false`" and across["measures"] == {}
    assert across["profiles"] is None


def test_the_section_says_why_numbers_are_missing(registry, tmp_path, measured, monkeypatch):
    out = tmp_path / "out"
    # no completed baseline run at all: nothing is measured
    mikt_only = {k: v for k, v in FINALS.items() if "vpg" not in k}
    study, _ = study_with(registry, tmp_path, mikt_only)
    study.report()
    assert "No aggregates across pairs: no completed `vpg` run yet: nothing to normalise by." in section(out)
    assert measured == []
    # the baseline on hopper only: ant's pair is left out, named
    study._remember("->hopper|vpg|0", fake_run(registry, "hopper", "vpg", 0, [0, 0, 10], 1))
    study._remember("->hopper|vpg|1", fake_run(registry, "hopper", "vpg", 1, [0, 0, 30], 1))
    study.report()
    text = section(out)
    assert "- no completed `vpg` run on ant yet: its pairs (four → ant) are left out" in text
    assert "| mikt | 2 | 1 | 2.50 [" in text and "| ant | — | — | 0 |" in text  # hopper's 2 and 3
    assert measured == [("hopper", 100, 0)]
    # a baseline no better than random on ant: its pair is left out of the measure, the rest reported
    monkeypatch.setitem(RANDOM, "ant", 100.0)
    for seed, final in ((0, 20), (1, 40)):
        study._remember(f"->ant|vpg|{seed}", fake_run(registry, "ant", "vpg", seed, [0, 0, final], 1))
    study.report()
    text = section(out)
    assert ("- `vpg` scores 30.0 (final return) on ant, no better than the random policy's 100.0: no scale to "
            "normalise on, its pairs (four → ant) are left out of the final return") in text
    assert "| mikt | 2 | 1 | 2.50 [" in text
    # a damaged cache: said in the section, the file left for the user, the report written
    (out / "random-returns.json").write_text("{not json")
    report = study.report()
    assert report.path.exists()
    assert "No aggregates across pairs: no random-policy returns: " in section(out)
    assert "random-returns.json cannot be read: JSONDecodeError" in section(out)
    assert (out / "random-returns.json").read_text() == "{not json"


def test_the_random_policy_measurement_is_seeded_and_whole_episodes():
    from miktcli.engine.random_policy import random_returns

    first = random_returns("hopper", episodes=2, seed=3)
    assert first == random_returns("hopper", episodes=2, seed=3)
    assert (first["episodes"], first["seed"], len(first["returns"])) == (2, 3, 2)
    assert first["return_mean"] == pytest.approx(sum(first["returns"]) / 2) and first["length_mean"] >= 1


def test_a_baseline_with_teachers_scales_each_pair_by_its_own_runs(registry, tmp_path, measured):
    study, _ = study_with(registry, tmp_path, baseline="mikt")
    study.report()
    text = section(tmp_path / "out")
    assert "normalised on its pair" in text and "not PPO from scratch" in text
    assert "| pair | R_random | R_mikt (final return) | n |" in text
    assert "| four → ant | 5.0 | 60 | 2 |" in text  # mikt's 50, 70 there: vpg's 20, 40 are (20 − 5) / 55 …
    assert "| four → hopper | 1.00 | 0.40 |" in text  # … and on hopper vpg's 10, 30 over mikt's 50: IQM 0.4
