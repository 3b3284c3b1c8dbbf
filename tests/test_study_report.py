"""A study's report: its numbers against a hand-computed grid, one weights panel per method, completed runs with
incomplete files left out and named, seeds' curves aligned by step; the numbers across pairs (scores normalised
between the random policy and the baseline, the IQM and P(X > Y) with stratified bootstrap intervals, performance
profiles, the random returns measured once per target into random-returns.json, the section saying why it is missing
where it cannot be built); and `--report-only`, which needs a study to report."""

import json
import warnings

import pytest

from helpers import fake_run, runner, vpg_grid
from miktcli.cli.app import app
from miktcli.engine.ppo import PPOConfig
from miktcli.registry.cards import RunConfig
from miktcli.registry.runs import create_run
from miktcli.studies.grid import Grid
from miktcli.studies.study import Study


def test_report_numbers_against_a_hand_computed_grid(registry, tmp_path):
    from miktcli.studies.grid import cell_key, load_grid
    from miktcli.studies.study import Study

    grid_file = tmp_path / "g.toml"
    grid_file.write_text(
        'name = "hand"\nsteps = 6144\nseeds = [0, 1]\nmarks = [4000, 6144]\nbaseline = "vpg"\n'
        '[[pairs]]\nfrom = ["a"]\nto = "hopper"\n[[pairs]]\nfrom = ["b"]\nto = "hopper"\n'
        '[[methods]]\nname = "mikt"\nmethod = "mikt"\n[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    grid = load_grid(grid_file)
    study = Study(grid, tmp_path / "out", registry)
    # vpg is shared by both pairs (same target): one run per seed, not one per pair
    assert len(study.distinct_cells()) == 2 * 2 + 2
    mix = {"p_pi_0": 0.9, "p_vf_0": 0.8}
    cells = {
        ("a", "mikt", 0): fake_run(registry, "hopper", "mikt", 0, [-10, -4, 2], 10, mix, teachers=["a"]),
        ("a", "mikt", 1): fake_run(registry, "hopper", "mikt", 1, [-6, -2, 6], 20, mix, teachers=["a"]),
        ("-", "vpg", 0): fake_run(registry, "hopper", "vpg", 0, [-12, -10, -6], 5),
        ("-", "vpg", 1): fake_run(registry, "hopper", "vpg", 1, [-8, -6, -2], 7),
    }
    pair_a = grid.pairs[0]
    methods = {m.name: m for m in grid.methods}
    for (_source, method, seed), run_id in cells.items():
        study.state.remember(cell_key(pair_a, methods[method], seed), run_id)
    from miktcli.registry.runs import open_run
    unfinished = fake_run(registry, "hopper", "mikt", 0, [-3, -2, -1], 0, teachers=["b"])
    open_run(registry, unfinished).save_card(status="created", steps_done=0, result={})  # prepared, never trained
    study.state.remember(cell_key(grid.pairs[1], methods["mikt"], 0), unfinished)
    study.report()
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    mikt, vpg = summary["a → hopper"]["mikt"], summary["a → hopper"]["vpg"]
    assert summary["b → hopper"]["vpg"]["runs"] == vpg["runs"]  # the shared baseline
    assert "mikt" not in summary["b → hopper"]
    # marks: 4000 reports the iteration at 2048 (the last at or before it), 6144 the last
    assert mikt["marks"] == {"2048": {"mean": -8.0, "std": 2 ** 0.5 * 2}, "6144": {"mean": 4.0, "std": 2 ** 0.5 * 2}}
    assert vpg["final_train_mean"] == -4.0 and vpg["final_eval_std"] == 2 ** 0.5
    # area under the curve: per-seed means (-4, -2/3) then mean and sample std over seeds
    assert abs(mikt["mean_over_training"] - (-4 - 2 / 3) / 2) < 1e-9
    # vpg final = -4 ≤ 0: ¾ of it is -5 (a quarter of |final| below), which mikt's mean curve
    # (-8, -3, 4) first reaches at 4096; vpg's own (-10, -8, -4) at 6144
    assert mikt["steps_to_three_quarters_of_baseline_final"] == "4,096"
    assert mikt["steps_to_baseline_final"] == "4,096"
    assert vpg["steps_to_three_quarters_of_baseline_final"] == "6,144"
    table = (tmp_path / "out" / "results.md").read_text()
    assert "![every pair](summary.png)" in table and (tmp_path / "out" / "summary.png").exists()
    assert "| method | n | 2,048 | 6,144 |" in table
    assert "| mikt | 2 | -8 ± 3 | 4 ± 3 |" in table
    # mikt against vpg over seeds: finals (2, 6) vs (-6, -2); of the 6 splits of the pooled four, {2, 6} and
    # {-6, -2} differ by 8, so p = 2/6, which is also the floor for 2 against 2
    assert "| mikt vs vpg | 2 / 2 | final return | +8 | 1.00 | 0.333 | 0.333 |" in table
    # final evals (10, 20) vs (5, 7): mean difference 9
    assert "| mikt vs vpg | 2 / 2 | final eval (no teacher) | +9 | 1.00 | 0.333 | 0.333 |" in table
    # the run table: each run's state and final numbers (these fake runs record no final train return)
    assert f"| a>hopper | mikt | 1 | {cells[('a', 'mikt', 1)]} | completed | — | 20 | — |" in table
    assert f"| b>hopper | mikt | 0 | {unfinished} | not started, 0/6,144 | — | — | — |" in table
    compared = json.loads((tmp_path / "out" / "comparisons.json").read_text())
    assert compared["b → hopper"] == []  # only vpg ran there: nothing to compare
    assert [(r["a"], r["b"], r["measure"]) for r in compared["a → hopper"]] == [
        ("mikt", "vpg", "final return"), ("mikt", "vpg", "mean over training"),
        ("mikt", "vpg", "final eval (no teacher)")]


def test_several_methods_weights_are_drawn_one_panel_per_method(monkeypatch, registry, tmp_path):
    """A screening of many multi-teacher methods drew every weight of every method on one set of axes
    (96 curves; tight_layout gave up with a warning): now each method has its panel, weights named alone."""
    from miktcli.studies import render_figures
    from miktcli.studies.grid import cell_key, load_grid
    from miktcli.studies.study import Study

    grid_file = tmp_path / "g.toml"
    grid_file.write_text('name = "w"\nsteps = 6144\nseeds = [0, 1]\nbaseline = "a"\n[[pairs]]\nfrom = ["x", "y"]\n'
                         'to = "hopper"\n[[methods]]\nname = "a"\nmethod = "mikt"\n'
                         '[[methods]]\nname = "b"\nmethod = "mikt"\n')
    study = Study(load_grid(grid_file), tmp_path / "out", registry)
    mix = {"p_pi_0": 0.5, "w_pi_0_t0": 0.3, "w_pi_0_t1": 0.2}
    for pair, method, seed in study.plan()[:3]:  # b has one seed of two
        study.state.remember(cell_key(pair, method, seed),
                        fake_run(registry, "hopper", "mikt", seed, [1, 2, 3], 5, mix, teachers=["x", "y"]))
    drawn = []
    real = render_figures.png_panels
    monkeypatch.setattr(render_figures, "png_panels",
                        lambda panels, path, ylabel, **kw: drawn.append((panels, path, ylabel, kw))
                        or real(panels, path, ylabel, **kw))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no layout warning
        study.report()
    (panels, path, ylabel, kw), = drawn
    assert path.name.startswith("weights-") and path.exists()
    assert [title for _, title, _ in panels] == ["a: student weights", "b: student weights"]
    assert all(sorted(series) == ["p_pi_0", "w_pi_0_t0", "w_pi_0_t1"] for series, _, _ in panels)
    assert ylabel == "weight (p: the student, w: each teacher)"
    assert kw["labels"][0] == {} and kw["labels"][1]["p_pi_0"] == "p_pi_0 (1 of 2 seeds)"


def test_completed_runs_with_incomplete_files_are_left_out_and_named(registry, tmp_path):
    from miktcli.registry.runs import open_run
    from miktcli.studies.grid import Grid
    from miktcli.studies.study import Study

    grid = Grid.model_validate({"name": "g", "steps": 6144, "seeds": [0, 1, 2], "marks": [2048, 6144],
                                "methods": [{"name": "vpg", "method": "vpg"}],
                                "pairs": [{"from": ["x"], "to": "hopper"}]})
    study = Study(grid, tmp_path / "out", registry)
    ids = [fake_run(registry, "hopper", "vpg", seed, [10, 20, 30 + seed], 5) for seed in range(3)]
    for seed, run_id in enumerate(ids):
        study.state.remember(f"->hopper|vpg|{seed}", run_id)
    truncated = open_run(registry, ids[1])
    truncated.metrics_path.write_text(truncated.metrics_path.read_text().splitlines(keepends=True)[0])
    no_eval = open_run(registry, ids[2])
    no_eval.save_card(result={})
    report = study.report()
    assert report.left_out == [f"{ids[1]}: metrics.jsonl ends at 2,048 steps, the run trained 6,144",
                               f"{ids[2]}: its card has no teacher-free eval result"]
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["x → hopper"]["vpg"]["runs"] == [ids[0]]  # the intact run alone, its curve whole
    assert summary["x → hopper"]["vpg"]["marks"] == {"2048": {"mean": 10.0, "std": None},
                                                     "6144": {"mean": 30.0, "std": None}}
    assert "Completed runs left out" in (tmp_path / "out" / "results.md").read_text()
    truncated.metrics_path.write_text("")  # nothing at all: still a named problem, not a crash
    assert study.report().left_out[0] == f"{ids[1]}: metrics.jsonl is empty, the run trained 6,144"


def test_a_pair_without_finished_runs_names_the_same_mark_columns(registry, tmp_path):
    from miktcli.studies.grid import Grid
    from miktcli.studies.study import Study

    grid = Grid.model_validate({"name": "g", "steps": 6144, "seeds": [0], "marks": [4000, 6144],
                                "methods": [{"name": "vpg", "method": "vpg"}],
                                "pairs": [{"from": ["x"], "to": "hopper"}, {"from": ["y"], "to": "ant"}]})
    study = Study(grid, tmp_path / "out", registry)
    study.state.remember("->hopper|vpg|0", fake_run(registry, "hopper", "vpg", 0, [10, 20, 30], 5))
    study.report()
    table = (tmp_path / "out" / "results.md").read_text()
    # 4000 is logged at 2048 (the last iteration at or before it): the empty ant table says so too
    assert table.count("| method | n | 2,048 | 6,144 |") == 2 and "4,000" not in table


# seeds' curves aligned by step; a run whose metrics do not cover every iteration it trained is left out, named -----

def completed_run(registry, seed, rows, *, n_steps=2048, mixing=None):
    """A completed vpg run on hopper with the given (steps, return) rows; it trained up to the last row's step."""
    config = RunConfig(ppo=PPOConfig(n_steps=n_steps), pi_hidden=[64, 64], vf_hidden=[64, 64])
    total = rows[-1][0]
    run = create_run(registry, kind="transfer", env="hopper", method="vpg", seed=seed, total_steps=total,
                     config=config, command="test", code_version="test", packages={})
    for steps, ret in rows:
        run.append_metrics({"iteration": steps // n_steps, "steps": steps, "return_mean": ret, **(mixing or {})})
    result = {"eval_without_teacher": {"return_mean": 1.0}}
    run.save_card(status="completed", steps_done=total, result=result)
    return run.id


def study_of(registry, tmp_path, seeds, marks=(8192,)):
    grid = Grid.model_validate({"name": "g", "steps": 8192, "seeds": seeds, "marks": list(marks),
                                "methods": [{"name": "vpg", "method": "vpg"}],
                                "pairs": [{"from": ["x"], "to": "hopper"}]})
    return Study(grid, tmp_path / "out", registry)


def steps_of(*iterations, n_steps=2048):
    return [n_steps * i for i in iterations]


def test_a_run_that_lost_leading_rows_is_left_out_and_named_not_aligned_by_row_index(registry, tmp_path):
    # the reported case: a run folder deleted while its cell trained is recreated by the next checkpoint, and the
    # run ends "completed" without its first rows; its last row still matches the steps it trained
    study = study_of(registry, tmp_path, [0, 1], marks=[4096, 8192])
    whole = completed_run(registry, 0, list(zip(steps_of(1, 2, 3, 4), [10, 20, 30, 40], strict=True)))
    gappy = completed_run(registry, 1, list(zip(steps_of(3, 4), [300, 400], strict=True)))
    study.state.remember("->hopper|vpg|0", whole)
    study.state.remember("->hopper|vpg|1", gappy)
    report = study.report()
    assert report.left_out == [f"{gappy}: metrics.jsonl lacks 2 of its 4 iterations' rows "
                               "(the first missing at 2,048 steps)"]
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    vpg = summary["x → hopper"]["vpg"]
    assert vpg["runs"] == [whole]  # the intact run alone, its curve whole (not cut to the other's two rows)
    assert vpg["marks"] == {"4096": {"mean": 20.0, "std": None}, "8192": {"mean": 40.0, "std": None}}
    assert f"- {gappy}: metrics.jsonl lacks 2 of its 4" in (tmp_path / "out" / "results.md").read_text()


def test_a_run_that_lost_a_middle_row_is_left_out_and_named(registry, tmp_path):
    study = study_of(registry, tmp_path, [0, 1])
    whole = completed_run(registry, 0, list(zip(steps_of(1, 2, 3, 4), [10, 20, 30, 40], strict=True)))
    gappy = completed_run(registry, 1, list(zip(steps_of(1, 2, 4), [1, 2, 4], strict=True)))
    study.state.remember("->hopper|vpg|0", whole)
    study.state.remember("->hopper|vpg|1", gappy)
    assert study.report().left_out == [f"{gappy}: metrics.jsonl lacks 1 of its 4 iterations' rows "
                                       "(the first missing at 6,144 steps)"]


def test_rows_at_steps_that_are_not_the_runs_iterations_are_named(registry, tmp_path):
    study = study_of(registry, tmp_path, [0])
    odd = completed_run(registry, 0, [(2048, 1), (4096, 2), (5000, 3), (6144, 3), (8192, 4)])
    study.state.remember("->hopper|vpg|0", odd)
    assert study.report().left_out == [f"{odd}: metrics.jsonl has a row at 5,000 steps, which is not one of "
                                       "its iterations (every 2,048 steps)"]


def test_seeds_with_different_rollout_sizes_are_compared_at_the_steps_they_share(registry, tmp_path):
    # one seed logs every 2,048 steps, the other every 4,096: by row index the second's 4,096 would be read
    # as the first's 2,048; by step they meet at 4,096 and 8,192
    study = study_of(registry, tmp_path, [0, 1], marks=[4096, 8192])
    fine = completed_run(registry, 0, list(zip(steps_of(1, 2, 3, 4), [10, 20, 30, 40], strict=True)))
    coarse = completed_run(registry, 1, [(4096, 60), (8192, 80)], n_steps=4096)
    study.state.remember("->hopper|vpg|0", fine)
    study.state.remember("->hopper|vpg|1", coarse)
    report = study.report()
    assert report.left_out == []
    vpg = json.loads((tmp_path / "out" / "summary.json").read_text())["x → hopper"]["vpg"]
    assert vpg["runs"] == [fine, coarse]
    assert {mark: cell["mean"] for mark, cell in vpg["marks"].items()} == {"4096": 40.0, "8192": 60.0}
    assert vpg["final_train_mean"] == 60.0


def test_a_seed_sharing_no_logged_step_with_the_others_is_left_out_and_named(registry, tmp_path):
    study = study_of(registry, tmp_path, [0, 1])
    fine = completed_run(registry, 0, list(zip(steps_of(1, 2, 3, 4), [10, 20, 30, 40], strict=True)))
    other = completed_run(registry, 1, [(3000, 1), (6000, 2), (9000, 3)], n_steps=3000)
    study.state.remember("->hopper|vpg|0", fine)
    study.state.remember("->hopper|vpg|1", other)
    assert study.report().left_out == [f"{other}: logs every 3,000 steps, at none of the steps {fine} logs at"]
    vpg = json.loads((tmp_path / "out" / "summary.json").read_text())["x → hopper"]["vpg"]
    assert vpg["runs"] == [fine] and vpg["final_train_mean"] == 40.0


def test_student_weight_curves_are_averaged_by_step(registry, tmp_path):
    from miktcli.registry.runs import open_run
    from miktcli.studies.summary import _weights

    mix = {"p_pi_0": 0.5, "p_vf_0": 0.25}
    fine = completed_run(registry, 0, list(zip(steps_of(1, 2, 3, 4), [1, 2, 3, 4], strict=True)), mixing=mix)
    coarse = completed_run(registry, 1, [(4096, 1), (8192, 2)], n_steps=4096, mixing={"p_pi_0": 1.0, "p_vf_0": 0.75})
    runs = [open_run(registry, r) for r in (fine, coarse)]
    for r, m in zip(runs, (mix, {"p_pi_0": 1.0, "p_vf_0": 0.75}), strict=True):
        r.save_card(result={**r.card.result, "final_mixing_learned": m})
    final, curves = _weights("mikt", runs)
    assert final == {"p_pi_0": 0.75, "p_vf_0": 0.5}
    assert curves["mikt p_pi_0"] == [(4096, 0.75), (8192, 0.75)]


# the numbers across pairs ------------------------------------------------------------------------------------------

RANDOM = {"hopper": 0.0, "ant": 5.0}
AGG_GRID = ('name = "agg"\nsteps = 6144\nseeds = [0, 1]\nbaseline = "{baseline}"\n{extra}'
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

    def initial(target, episodes, seed):  # the initial policy: shown beside R_random, 10 below it here
        return {"episodes": episodes, "seed": seed, "return_mean": RANDOM[target] - 10, "return_std": 0.0,
                "length_mean": 20.0, "returns": [RANDOM[target] - 10] * episodes}

    monkeypatch.setattr("miktcli.studies.random_cache.random_returns", measure)
    monkeypatch.setattr("miktcli.studies.random_cache.initial_policy_returns", initial)
    return calls


def study_with(registry, tmp_path, cells=FINALS, extra="", baseline="vpg"):
    from miktcli.studies.grid import load_grid
    from miktcli.studies.study import Study

    grid_file = tmp_path / "agg.toml"
    grid_file.write_text(AGG_GRID.format(extra=extra, baseline=baseline))
    study = Study(load_grid(grid_file), tmp_path / "out", registry)
    for key, final in cells.items():
        target, method, seed = key.split(">")[1].split("|")
        teachers = [] if method == "vpg" else ["four"]
        study.state.remember(key, fake_run(registry, target, method, int(seed), [0, 0, final], 1, teachers=teachers))
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
    assert "| ant | 5.0 | -5.0 | 30 | 2 |" in text and "| hopper | 0.0 | -10.0 | 20 | 2 |" in text
    assert "random-returns.json and initial-policy-returns.json in this folder" in text and "Left out" not in text
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
    assert across["normalisation"][1] == {"task": "ant", "random": 5.0, "runs": 2, "initial": -5.0,
                                          "reference": {"final return": 30.0, "mean over training": 10.0}}
    assert across["profiles"] == {"figure": "aggregate-profile.png", "measure": "final return",
                                  "methods": ["mikt", "vpg"]}
    # each target measured once, by the committed protocol, and cached with its provenance
    assert measured == [("hopper", 100, 0), ("ant", 100, 0)]
    initial = json.loads((out / "initial-policy-returns.json").read_text())
    assert initial["policy"].startswith("N(0, 1)") and initial["targets"]["ant"]["return_mean"] == -5.0
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
    study.state.remember("->hopper|vpg|0", fake_run(registry, "hopper", "vpg", 0, [0, 0, 10], 1))
    study.state.remember("->hopper|vpg|1", fake_run(registry, "hopper", "vpg", 1, [0, 0, 30], 1))
    study.report()
    text = section(out)
    assert "- no completed `vpg` run on ant yet: its pairs (four → ant) are left out" in text
    assert "| mikt | 2 | 1 | 2.50 [" in text and "| ant | — | — | — | 0 |" in text  # hopper's 2 and 3
    assert measured == [("hopper", 100, 0)]
    # a baseline no better than random on ant: its pair is left out of the measure, the rest reported
    monkeypatch.setitem(RANDOM, "ant", 100.0)
    for seed, final in ((0, 20), (1, 40)):
        study.state.remember(f"->ant|vpg|{seed}", fake_run(registry, "ant", "vpg", seed, [0, 0, final], 1))
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


TEACHER_COUNTS_GRID = ('name = "counts"\nsteps = 6144\nseeds = [0, 1]\n'
                       '[[pairs]]\nfrom = ["four"]\nto = "hopper"\n[[pairs]]\nfrom = ["four", "six"]\nto = "hopper"\n'
                       '[[pairs]]\nfrom = ["four", "eight"]\nto = "hopper"\n'
                       '[[methods]]\nname = "mikt"\nmethod = "mikt"\n[[methods]]\nname = "vpg"\nmethod = "vpg"\n')


def test_one_and_two_teacher_runs_are_pooled_apart_and_compared_on_the_same_tasks(registry, tmp_path, measured):
    from miktcli.studies.grid import load_grid

    grid_file = tmp_path / "counts.toml"
    grid_file.write_text(TEACHER_COUNTS_GRID)
    study = Study(load_grid(grid_file), tmp_path / "out", registry)
    # R_vpg 20 on hopper (random 0): one teacher scores 2, 3; four + six 4, 5; four + eight 3, 4
    finals = {"->hopper|vpg|0": 10, "->hopper|vpg|1": 30, "four>hopper|mikt|0": 40, "four>hopper|mikt|1": 60,
              "four+six>hopper|mikt|0": 80, "four+six>hopper|mikt|1": 100,
              "four+eight>hopper|mikt|0": 60, "four+eight>hopper|mikt|1": 80}
    for key, final in finals.items():
        teachers = key.split(">")[0].split("+") if key[0] != "-" else []
        method, seed = key.split("|")[1:]
        study.state.remember(key, fake_run(registry, "hopper", method, int(seed), [0, 0, final], 1,
                                           teachers=teachers))
    study.report()
    final = section(tmp_path / "out").split("### Final return")[1].split("### Mean over training")[0]
    # two-teacher runs pooled: 3, 4, 4, 5 → IQM 4; one teacher 2, 3; vpg's runs once, not once per pair
    assert "| mikt, 1 teacher | 2 | 1 | 2.50 [" in final and "| mikt, 2 teachers | 4 | 2 | 4.00 [" in final
    assert "| vpg | 2 | 1 | 1.00 [" in final
    # each two-teacher pair against four alone on hopper: 2 tasks, the intervals apart
    assert "| mikt, 2 teachers vs mikt, 1 teacher | 2 | 4.00 [" in final
    # P(X > Y): 1 on four + six; on four + eight 3, 4 against 2, 3 is 3.5 of 4 (a tie counts half)
    assert "| 4.00 [3.50, 4.50] | 2.50 [2.00, 3.00] | no | 0.94 [" in final
    matched = json.loads((tmp_path / "out" / "summary.json").read_text())["across_pairs"]["measures"][
        "final return"]["more_teachers_vs_fewer"]
    assert [(m["x"], m["y"], m["tasks"], m["intervals_overlap"]) for m in matched] == [
        ("mikt, 2 teachers", "mikt, 1 teacher", 2, False)]


def test_the_initial_policy_measurement_is_seeded_and_scores_below_the_uniform_one():
    from miktcli.engine.random_policy import initial_policy_returns, random_returns

    first = initial_policy_returns("hopper", episodes=3, seed=1)
    assert first == initial_policy_returns("hopper", episodes=3, seed=1)
    assert first["returns"] != random_returns("hopper", episodes=3, seed=1)["returns"]
    assert (first["episodes"], len(first["returns"])) == (3, 3) and first["length_mean"] >= 1


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
    assert "| pair | R_random (uniform) | R_initial (N(0, 1)) | R_mikt (final return) | n |" in text
    assert "| four → ant | 5.0 | -5.0 | 60 | 2 |" in text  # mikt's 50, 70 there: vpg's 20, 40 are (20 − 5) / 55 …
    assert "| four → hopper | 1.00 | 0.40 |" in text  # … and on hopper vpg's 10, 30 over mikt's 50: IQM 0.4


# --report-only -----------------------------------------------------------------------------------------------------

def test_report_only_on_a_missing_or_empty_folder_is_one_line(registry, tmp_path):
    grid = vpg_grid(tmp_path)
    for out in (tmp_path / "missing", tmp_path / "empty"):
        if out.name == "empty":
            out.mkdir()
        r = runner.invoke(app, ["study", str(grid), "--out", str(out), "--report-only"])
        assert r.exit_code == 1, r.output
        assert f"Error: {out} holds no study yet (no state.json): nothing to report" in r.output
        assert not (out / "results.md").exists()
    assert not (tmp_path / "missing").exists()


def test_report_only_on_a_prepared_study_reports_it(registry, tmp_path):
    from miktcli.studies.grid import load_grid
    from miktcli.studies.study import Study

    grid = vpg_grid(tmp_path)
    Study(load_grid(grid), tmp_path / "out", registry).prepare("test")  # prepared, nothing finished yet
    r = runner.invoke(app, ["study", str(grid), "--out", str(tmp_path / "out"), "--report-only"])
    assert r.exit_code == 0 and (tmp_path / "out" / "results.md").exists(), r.output
