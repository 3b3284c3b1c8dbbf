import json
import warnings
from pathlib import Path

from typer.testing import CliRunner

from helpers import fake_run
from miktcli.cli.app import app
from miktcli.registry.cards import code_version

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
    assert table.count(f"| {code_version()} from step 0 |") == 4  # which code trained each run
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
        study._remember(cell_key(pair_a, methods[method], seed), run_id)
    from miktcli.registry.runs import open_run
    unfinished = fake_run(registry, "hopper", "mikt", 0, [-3, -2, -1], 0, teachers=["b"])
    open_run(registry, unfinished).save_card(status="created", steps_done=0, result={})  # prepared, never trained
    study._remember(cell_key(grid.pairs[1], methods["mikt"], 0), unfinished)
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
        study._remember(cell_key(pair, method, seed),
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
        study._remember(f"->hopper|vpg|{seed}", run_id)
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
    study._remember("->hopper|vpg|0", fake_run(registry, "hopper", "vpg", 0, [10, 20, 30], 5))
    study.report()
    table = (tmp_path / "out" / "results.md").read_text()
    # 4000 is logged at 2048 (the last iteration at or before it): the empty ant table says so too
    assert table.count("| method | n | 2,048 | 6,144 |") == 2 and "4,000" not in table


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


def test_unknown_teacher_is_found_before_any_cell_trains(registry, tmp_path):
    grid = tmp_path / "g.toml"
    grid.write_text('name = "x"\nsteps = 2048\nseeds = [0]\n[[pairs]]\nfrom = ["ghost"]\nto = "hopper"\n'
                    '[[methods]]\nname = "vpg"\nmethod = "vpg"\n[[methods]]\nname = "mikt"\nmethod = "mikt"\n')
    r = runner.invoke(app, ["study", str(grid), "--out", str(tmp_path / "o")])
    assert r.exit_code == 1 and "unknown teacher 'ghost'" in r.output
    assert not (registry / "runs").exists()


def test_a_cell_whose_run_id_now_names_another_run_is_an_error_not_a_result(registry, tmp_path):
    """state.json outliving its runs (a registry restored or reset) must not credit a cell with another run."""
    from miktcli.studies.grid import cell_key, load_grid
    from miktcli.studies.study import Study

    grid_file = tmp_path / "g.toml"
    grid_file.write_text('name = "g"\nsteps = 6144\nseeds = [0]\n[[pairs]]\nfrom = ["x"]\nto = "hopper"\n'
                         '[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    study = Study(load_grid(grid_file), tmp_path / "out", registry)
    other = fake_run(registry, "ant", "vpg", 0, [1, 2, 3], 5)  # a finished run of another cell
    study._remember(cell_key(*study.plan()[0]), other)
    for args in (["--report-only"], []):
        r = runner.invoke(app, ["study", str(grid_file), "--out", str(tmp_path / "out"), *args])
        assert r.exit_code == 1, r.output
        assert f"names {other}, but {other} is a transfer run of vpg on ant, seed 0" in r.output
    assert not (registry / "runs" / "run2").exists()  # nothing trained or created meanwhile


def test_a_run_recording_the_budget_as_asked_still_is_its_cell_and_a_wrong_budget_names_both(registry, tmp_path):
    """Runs made before budgets were rounded up to whole rollouts record the budget as asked (500,000, not
    501,760): they are still their cell's run. A run of another budget is refused, naming the rounded figure."""
    from miktcli.registry.runs import open_run
    from miktcli.studies.grid import cell_key, load_grid
    from miktcli.studies.study import Study

    grid_file = tmp_path / "g.toml"
    grid_file.write_text('name = "g"\nsteps = 5000\nseeds = [0]\n[[pairs]]\nfrom = ["x"]\nto = "hopper"\n'
                         '[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    study = Study(load_grid(grid_file), tmp_path / "out", registry)
    run_id = fake_run(registry, "hopper", "vpg", 0, [1, 2], 5)  # records 4,096 steps
    study._remember(cell_key(*study.plan()[0]), run_id)
    r = runner.invoke(app, ["study", str(grid_file), "--out", str(tmp_path / "out"), "--report-only"])
    assert r.exit_code == 1 and "trains 4,096 steps, the grid 5,000 (6,144 in whole rollouts of 2,048)" in r.output
    open_run(registry, run_id).save_card(total_steps=5000)  # the budget as asked, as mikt before 9519580 wrote it
    r = runner.invoke(app, ["study", str(grid_file), "--out", str(tmp_path / "out"), "--report-only"])
    assert r.exit_code == 0, r.output
    assert "| vpg | 1 |" in (tmp_path / "out" / "results.md").read_text()


def test_a_study_start_turns_never_trained_running_or_interrupted_cells_into_created(registry, tmp_path):
    from miktcli.registry.runs import open_run
    from miktcli.studies.grid import load_grid
    from miktcli.studies.study import Study

    grid_file = tmp_path / "g.toml"
    grid_file.write_text('name = "g"\nsteps = 6144\nseeds = [0, 1, 2]\n[[pairs]]\nfrom = ["x"]\nto = "hopper"\n'
                         '[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    study = Study(load_grid(grid_file), tmp_path / "out", registry)
    runs = [run for _, run in study.prepare("test")]
    runs[0].save_card(status="running")  # prepared before the `created` status
    runs[1].save_card(status="interrupted")  # marked by an older Ray driver that held it
    runs[2].save_card(status="interrupted", steps_done=2048)  # really trained: left alone
    study.prepare("test")
    assert [open_run(registry, r.id).card.status for r in runs] == ["created", "created", "interrupted"]


def test_the_ray_progress_overview_counts_cells_and_estimates_the_end():
    from miktcli.cli.study import _overview
    from miktcli.studies.ray_executor import CellProgress

    cells = [CellProgress("a", "run1", 100, steps=100, state="completed"),
             CellProgress("b", "run2", 100, steps=40, steps_per_sec=5.0, state="training"),
             CellProgress("c", "run3", 100, steps=0, steps_per_sec=5.0, state="training"),
             CellProgress("d", "run4", 100, steps=0, state="queued"),
             CellProgress("e", "run5", 100, steps=10, state="failed")]
    # 3 finished before this driver started + run1; 60 + 100 + 100 steps left at 10 steps/s together
    assert _overview(cells, finished_before=3) == (
        "4/8 cells completed, 2 training, 1 failed; 260 steps to go, about 0:00:26 at the current 10 steps/s")
    assert _overview(cells[:1], finished_before=0) == "1/1 cells completed, 0 training; 0 steps to go"


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

    grids = sorted((GRID.parent).glob("*.toml"))
    assert any(g.name == "multi-screen.toml" for g in grids)
    for path in grids:
        grid = load_grid(path)
        for method in grid.methods:  # what the study does before the first cell: an unknown option fails here
            get_method(method.method).parse_options(method.options)
        if grid.name == "multi-screen":
            assert len(Study(grid, Path("/nonexistent"), Path("/nonexistent")).distinct_cells()) <= 16
