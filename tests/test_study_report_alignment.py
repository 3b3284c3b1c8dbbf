"""A study report aligns its seeds' curves by step, and leaves out (naming it) a run whose metrics do not
cover every iteration it trained (issue 37 A)."""

import json

from miktcli.engine.ppo import PPOConfig
from miktcli.registry.cards import RunConfig
from miktcli.registry.runs import create_run
from miktcli.studies.grid import Grid
from miktcli.studies.study import Study


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
    # the case: a run folder deleted while its cell trained is recreated by the next checkpoint, and the
    # run ends "completed" without its first rows; its last row still matches the steps it trained
    study = study_of(registry, tmp_path, [0, 1], marks=[4096, 8192])
    whole = completed_run(registry, 0, list(zip(steps_of(1, 2, 3, 4), [10, 20, 30, 40], strict=True)))
    gappy = completed_run(registry, 1, list(zip(steps_of(3, 4), [300, 400], strict=True)))
    study._remember("->hopper|vpg|0", whole)
    study._remember("->hopper|vpg|1", gappy)
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
    study._remember("->hopper|vpg|0", whole)
    study._remember("->hopper|vpg|1", gappy)
    assert study.report().left_out == [f"{gappy}: metrics.jsonl lacks 1 of its 4 iterations' rows "
                                       "(the first missing at 6,144 steps)"]


def test_rows_at_steps_that_are_not_the_runs_iterations_are_named(registry, tmp_path):
    study = study_of(registry, tmp_path, [0])
    odd = completed_run(registry, 0, [(2048, 1), (4096, 2), (5000, 3), (6144, 3), (8192, 4)])
    study._remember("->hopper|vpg|0", odd)
    assert study.report().left_out == [f"{odd}: metrics.jsonl has a row at 5,000 steps, which is not one of "
                                       "its iterations (every 2,048 steps)"]


def test_seeds_with_different_rollout_sizes_are_compared_at_the_steps_they_share(registry, tmp_path):
    # one seed logs every 2,048 steps, the other every 4,096: by row index the second's 4,096 would be read
    # as the first's 2,048; by step they meet at 4,096 and 8,192
    study = study_of(registry, tmp_path, [0, 1], marks=[4096, 8192])
    fine = completed_run(registry, 0, list(zip(steps_of(1, 2, 3, 4), [10, 20, 30, 40], strict=True)))
    coarse = completed_run(registry, 1, [(4096, 60), (8192, 80)], n_steps=4096)
    study._remember("->hopper|vpg|0", fine)
    study._remember("->hopper|vpg|1", coarse)
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
    study._remember("->hopper|vpg|0", fine)
    study._remember("->hopper|vpg|1", other)
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
