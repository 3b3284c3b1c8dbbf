"""The scripts under benchmarks/ that build committed evidence from run snapshots."""

import importlib.util
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from helpers import fake_run

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def load_script(name: str):
    if str(BENCHMARKS) not in sys.path:  # as when run as `python benchmarks/NAME.py`: its helpers import
        sys.path.insert(0, str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # a script's dataclasses look their module up while it runs
    spec.loader.exec_module(module)
    return module


class Ran:
    def __init__(self, returncode: int, stdout: str, stderr: str):
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


def snapshot_script(*args, check: bool = True) -> Ran:
    """`python benchmarks/snapshot_study.py ARGS`, run in this process (a fresh interpreter per call cost these
    tests a minute): its exit code, what it printed, and its `sys.exit` message as stderr."""
    import contextlib
    import io
    import runpy
    from unittest import mock

    stdout, code, message = io.StringIO(), 0, ""
    with mock.patch.object(sys, "argv", ["snapshot_study.py", *map(str, args)]), contextlib.redirect_stdout(stdout):
        try:
            runpy.run_path(str(BENCHMARKS / "snapshot_study.py"), run_name="__main__")
        except SystemExit as stop:
            code, message = (1, str(stop.code)) if isinstance(stop.code, str) else (stop.code or 0, "")
    if check and code:
        raise AssertionError(f"snapshot_study.py {args} exited {code}: {message}")
    return Ran(code, stdout.getvalue(), message)


GRID = ('name = "{name}"\nsteps = 6144\nseeds = {seeds}\nmarks = [4096, 6144]\nbaseline = "{baseline}"\n{pairs}'
        '[[methods]]\nname = "mikt"\nmethod = "mikt"\n{extra}')


def test_similarity_report_puts_every_teacher_of_the_target_on_the_same_seeds(registry, tmp_path):
    grids, results = tmp_path / "grids", tmp_path / "results"
    grids.mkdir()
    (grids / "main.toml").write_text(GRID.format(
        name="main", seeds="[0, 1, 2]", baseline="vpg", extra='[[methods]]\nname = "vpg"\nmethod = "vpg"\n',
        pairs='[[pairs]]\nfrom = ["four"]\nto = "hopper"\n[[pairs]]\nfrom = ["four"]\nto = "ant"\n'))
    (grids / "sim.toml").write_text(GRID.format(
        name="sim", seeds="[0, 1]", baseline="mikt", extra="", pairs='[[pairs]]\nfrom = ["far"]\nto = "hopper"\n'))
    mix = {"p_pi_0": 0.5, "p_vf_0": 0.25}
    main_cells = {  # seed 2 of the main grid is not on the similarity grid's seeds: left out
        "four>hopper|mikt|0": fake_run(registry, "hopper", "mikt", 0, [1, 2, 3], 30, mix),
        "four>hopper|mikt|1": fake_run(registry, "hopper", "mikt", 1, [3, 4, 5], 50, mix),
        "four>hopper|mikt|2": fake_run(registry, "hopper", "mikt", 2, [100, 100, 100], 999, mix),
        "->hopper|vpg|0": fake_run(registry, "hopper", "vpg", 0, [0, 0, 1], 10),
        "->hopper|vpg|1": fake_run(registry, "hopper", "vpg", 1, [0, 0, 3], 20),
        "four>ant|mikt|0": fake_run(registry, "ant", "mikt", 0, [7, 7, 7], 7, mix),  # another target
    }
    sim_cells = {"far>hopper|mikt|0": fake_run(registry, "hopper", "mikt", 0, [0, 1, 1], 5, mix)}
    for study, cells in (("main", main_cells), ("sim", sim_cells)):
        (results / study).mkdir(parents=True)
        (results / study / "state.json").write_text(json.dumps(cells))
        for run_id in cells.values():  # what benchmarks/snapshot_study.py copies
            shutil.copytree(registry / "runs" / run_id, results / study / "runs" / run_id)
    shutil.rmtree(registry)  # the report needs the snapshots only

    path = load_script("similarity_report").similarity_report(results, "main", "sim", grids=grids)
    rows = {line.split(" | ")[0].strip("| "): line for line in path.read_text().splitlines()
            if line.startswith("| ") and not line.startswith("| curve") and " vs " not in line}
    assert rows.keys() == {"mikt ← four", "mikt ← far", "vpg"}
    # seeds 0 and 1 only: at 4096 steps 2 and 4, at 6144 3 and 5, mean over training 2 and 4, eval 30 and 50
    assert rows["mikt ← four"] == "| mikt ← four | 2 | 3 ± 1 | 4 ± 1 | 3 ± 1 | 40 ± 14 | 0.50 / 0.25 |"
    assert rows["mikt ← far"] == "| mikt ← far | 1 | 1 | 1 | 1 | 5 | 0.50 / 0.25 |"
    assert rows["vpg"] == "| vpg | 2 | 0 ± 0 | 2 ± 1 | 1 ± 0 | 15 ± 7 | — |"
    # over seeds: the teachers with two runs each are compared (final 3, 5 against 1, 3); one run is not enough
    compared = [line for line in path.read_text().splitlines() if line.startswith("| mikt ← ") and " vs " in line]
    assert [line.split(" | ")[:3] for line in compared] == [
        ["| mikt ← four vs vpg", "2 / 2", measure] for measure in ("final return", "mean over training",
                                                                    "final eval (no teacher)")]
    assert compared[0] == "| mikt ← four vs vpg | 2 / 2 | final return | +2 | 0.88 | 0.667 | 0.333 |"
    assert (path.parent / "similarity-curves.png").exists() and (path.parent / "similarity-weights.png").exists()


def test_a_student_weight_curve_is_counted_like_its_return_curve():
    from miktcli.studies import across_studies as cross

    found = cross.Curves(per_seed={"mikt ← far": {"final return": np.array([1.0])},
                                   "vpg": {"final return": np.array([1.0, 2.0])}},
                         weights={cross.weight_label("mikt ← far"): [(2048, 0.5)]})
    assert found.weight_counts == {"mikt ← far (π)": 1}  # vpg mixes nothing: no weight curve to label


def test_controls_report_puts_the_main_grids_runs_beside_the_controls_on_common_seeds(registry, tmp_path):
    grids, results = tmp_path / "grids", tmp_path / "results"
    grids.mkdir()
    pairs = '[[pairs]]\nfrom = ["four"]\nto = "hopper"\n'
    (grids / "main.toml").write_text(GRID.format(
        name="main", seeds="[0, 1, 2]", baseline="vpg", extra='[[methods]]\nname = "vpg"\nmethod = "vpg"\n',
        pairs=pairs + '[[pairs]]\nfrom = ["six"]\nto = "hopper"\n'))
    (grids / "ctl.toml").write_text('name = "ctl"\nsteps = 6144\nseeds = [0, 1]\nmarks = [4096, 6144]\n'
                                    'baseline = "vpg + KL"\n' + pairs
                                    + '[[methods]]\nname = "vpg + KL"\nmethod = "vpg"\nkl_coef = 0.05\n')
    (grids / "abl.toml").write_text('name = "abl"\nsteps = 6144\nseeds = [0, 1, 2]\nmarks = [4096, 6144]\n'
                                    'baseline = "mikt w/o MI"\n' + pairs
                                    + '[[methods]]\nname = "mikt w/o MI"\nmethod = "mikt"\nmikt = { mi = false }\n')
    mix = {"p_pi_0": 1.0, "p_vf_0": 1.0}
    cells = {
        "main": {"four>hopper|mikt|0": fake_run(registry, "hopper", "mikt", 0, [1, 2, 9], 30, mix),
                 "four>hopper|mikt|1": fake_run(registry, "hopper", "mikt", 1, [3, 4, 11], 50, mix),
                 "four>hopper|mikt|2": fake_run(registry, "hopper", "mikt", 2, [99, 99, 99], 999, mix),  # seed 2
                 "six>hopper|mikt|0": fake_run(registry, "hopper", "mikt", 0, [50, 50, 50], 50, mix),  # other pair
                 "->hopper|vpg|0": fake_run(registry, "hopper", "vpg", 0, [0, 0, 1], 10),
                 "->hopper|vpg|1": fake_run(registry, "hopper", "vpg", 1, [0, 0, 3], 20)},
        "ctl": {"->hopper|vpg + KL|0": fake_run(registry, "hopper", "vpg", 0, [0, 1, 2], 12)},
        "abl": {},  # not started: its curve has n = 0
    }
    for study, runs in cells.items():
        (results / study).mkdir(parents=True)
        (results / study / "state.json").write_text(json.dumps(runs))
        for run_id in runs.values():
            shutil.copytree(registry / "runs" / run_id, results / study / "runs" / run_id)
    shutil.rmtree(registry)

    path = load_script("controls_report").controls_report(results, "main", ["ctl", "abl"], grids=grids)
    text = path.read_text()
    assert "## four → hopper (seeds [0, 1])" in text and "six" not in text  # seeds both control grids have
    rows = {line.split(" | ")[0].strip("| "): line for line in text.splitlines()
            if line.startswith("| ") and not line.startswith(("| curve", "| A vs B"))}
    assert rows["mikt"] == "| mikt | 2 | 3 ± 1 | 10 ± 1 | 5 ± 1 | 40 ± 14 | 1.00 / 1.00 |"
    assert rows["vpg"] == "| vpg | 2 | 0 ± 0 | 2 ± 1 | 1 ± 0 | 15 ± 7 | — |"
    assert rows["vpg + KL"] == "| vpg + KL | 1 | 1 | 2 | 1 | 12 | — |"
    assert rows["mikt w/o MI"].startswith("| mikt w/o MI | 0 | — |")
    # over seeds: 2 against 2 can be compared, 2 against 1 cannot
    compared = [line for line in text.splitlines() if line.startswith("| mikt vs vpg |")]
    assert compared[0] == "| mikt vs vpg | 2 / 2 | final return | +8 | 1.00 | 0.333 | 0.333 |" and len(compared) == 3
    assert "vs vpg + KL" not in text
    assert (results / "controls-four-to-hopper.png").exists()


def test_snapshots_restore_into_a_fresh_registry_so_the_study_skips_finished_cells(registry, tmp_path):
    from miktcli.studies.grid import cell_key, load_grid
    from miktcli.studies.study import Study

    grid_file = tmp_path / "g.toml"
    grid_file.write_text('name = "g"\nsteps = 6144\nseeds = [0, 1, 2]\n[[pairs]]\nfrom = ["x"]\nto = "hopper"\n'
                         '[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    grid, out = load_grid(grid_file), tmp_path / "out"
    study = Study(grid, out, registry)
    key0, key1, key2 = (cell_key(*cell) for cell in study.plan())
    unfinished = study.prepare("test")[1][1].id  # run1-run3 prepared; seed 1's and seed 2's never train
    finished = fake_run(registry, "hopper", "vpg", 0, [1, 2, 3], 5)  # run4, seed 0's
    study.state.remember(key0, finished)
    script = [out, "--registry", registry]
    snapshot_script(*script)
    assert (out / "runs" / finished / "metrics.jsonl").exists() and not (out / "runs" / unfinished).exists()
    lost = (registry / "runs" / unfinished).rename(tmp_path / "lost")  # a run the registry lacks: named,
    shutil.rmtree(out / "runs")                                        # the others still copied
    r = snapshot_script(*script)
    assert f"{unfinished}  {key1}: not in" in r.stdout and (out / "runs" / finished / "run.json").exists()
    lost.rename(registry / "runs" / unfinished)

    saved = registry.rename(tmp_path / "old-registry")  # a fresh clone: the committed results, no run folders
    snapshot_script(*script, "--restore")
    assert json.loads((out / "state.json").read_text()) == {key0: finished}  # unfinished cells start afresh
    cells = dict(Study(grid, out, registry).prepare("test"))
    assert cells[key0].id == finished and cells[key0].card.status == "completed"  # not trained again
    assert cells[key1].id == "run5" and cells[key2].id == "run6"  # new ids after the restored run4

    # a registry holding other runs under the snapshot's ids: refused, nothing changed
    other = tmp_path / "other"
    shutil.copytree(saved, other)
    shutil.rmtree(other / "runs" / finished)
    fake_run(other, "hopper", "vpg", 2, [0], 0)  # another run, same id as the snapshot's
    state_before = (out / "state.json").read_text()
    r = snapshot_script(out, "--registry", other, "--restore", check=False)
    assert r.returncode == 1 and "already has other runs under these ids: run4" in r.stderr
    assert (out / "state.json").read_text() == state_before



@pytest.mark.slow
def test_an_in_flight_snapshot_carries_an_unfinished_run_to_another_machine(registry, tmp_path, monkeypatch,
                                                                            ctrl_c_at_second_update):
    from typer.testing import CliRunner

    from miktcli.cli.app import app
    from miktcli.engine.ppo import PPOTrainer
    from miktcli.registry.runs import RunLock, open_run

    grid_file, out = tmp_path / "g.toml", tmp_path / "out"
    grid_file.write_text('name = "g"\nsteps = 6144\nseeds = [0]\n[[pairs]]\nfrom = ["x"]\nto = "hopper"\n'
                         '[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    runner = CliRunner()
    assert runner.invoke(app, ["study", str(grid_file), "--out", str(out)]).exit_code != 0  # Ctrl-C, 2nd update
    ctrl_c_at_second_update()
    (run_id,) = json.loads((out / "state.json").read_text()).values()
    assert open_run(registry, run_id).card.steps_done == 2048
    script = [out, "--registry", registry]

    lock = RunLock(open_run(registry, run_id)).acquire()  # a study still training it: refused, nothing kept
    r = snapshot_script(*script, "--in-flight", check=False)
    assert r.returncode == 1 and f"{run_id} still training: its checkpoint could change" in r.stderr
    assert not (out / "in-flight").exists()
    lock.release()

    snapshot_script(*script, "--in-flight")
    kept = out / "in-flight" / run_id
    assert sorted(p.name for p in kept.iterdir()) == ["checkpoint.safetensors", "metrics.jsonl", "run.json"]
    registry.rename(tmp_path / "old-registry")  # another machine: the committed results only
    r = snapshot_script(*script, "--restore")
    assert "in flight: resumes" in r.stdout
    updates, update = [], PPOTrainer.update
    monkeypatch.setattr(PPOTrainer, "update", lambda self, batch: updates.append(1) or update(self, batch))
    r = runner.invoke(app, ["study", str(grid_file), "--out", str(out)])
    assert r.exit_code == 0, r.output
    run = open_run(registry, run_id)  # resumed from its checkpoint under its own id: two updates, not three
    assert run.card.status == "completed" and [m["steps"] for m in run.read_metrics()] == [2048, 4096, 6144]
    assert len(updates) == 2
    snapshot_script(*script)  # the finished snapshot supersedes the in-flight one
    assert (out / "runs" / run_id / "run.json").exists() and not kept.exists()
    assert not (out / "in-flight").exists()  # nor its folder, once the last in-flight run has finished

def test_every_committed_grid_loads():
    from miktcli.studies.grid import load_grid

    grids = sorted((BENCHMARKS / "grids").glob("*.toml"))
    assert len(grids) >= 9
    for path in grids:
        load_grid(path)


@pytest.mark.slow
def test_handover_remeasure_measures_each_run_once_per_episode_count_and_keeps_earlier_ones(registry, teacher,
                                                                                         tmp_path, monkeypatch):
    from helpers import mikt

    remeasure = load_script("handover_remeasure")
    run = json.loads(mikt("transfer", "--from", "tiny", "--to", "hopper", "--steps", 10240, "--ramp-start", 0.2,
                          "--drop-teacher-at", 0.5, "--eval-episodes", 2, "--json").stdout)
    vpg = json.loads(mikt("transfer", "--to", "hopper", "--method", "vpg", "--steps", 2048, "--eval-episodes", 1,
                          "--json").stdout)["run"]
    results = tmp_path / "study"
    results.mkdir()
    (results / "state.json").write_text(json.dumps({"tiny@v1>hopper|mikt|0": run["run"], "->hopper|vpg|0": vpg}))
    remeasure.main([str(results), "--registry", str(registry), "--episodes", "2"])
    record = json.loads((results / "handover-remeasured.json").read_text())
    assert list(record["runs"]) == [run["run"]]  # the PPO run has no drop
    two = record["runs"][run["run"]]["measured"]["2"]
    assert two["kept_fraction"] == run["handover"]["kept_fraction"]  # the card's episodes: the card's numbers
    assert record["runs"][run["run"]]["card"]["episodes"] == 2
    monkeypatch.setattr(remeasure, "measure_handover", lambda *a: pytest.fail("measured twice"))
    remeasure.main([str(results), "--registry", str(registry), "--episodes", "2"])  # nothing new to measure
    monkeypatch.undo()
    remeasure.main([str(results), "--registry", str(registry), "--episodes", "3"])
    record = json.loads((results / "handover-remeasured.json").read_text())
    assert sorted(record["runs"][run["run"]]["measured"]) == ["2", "3"]
    table = (results / "handover-remeasured.md").read_text()
    assert "tiny@v1>hopper|mikt" in table and "3 episodes" in table


def test_teachers_vs_cat_reads_both_sides_over_the_window_before_cat_s_checkpoint(tmp_path, capsys):
    script = load_script("teachers_vs_cat")
    for cat_name in script.NAMES.values():
        for seed in range(5):
            folder = tmp_path / cat_name / str(seed)
            folder.mkdir(parents=True)
            # 976 updates: 100 outside the window, 10 + seed inside it (updates 961-970)
            rows = ["eprewmean,nupdates", *(f"{10 + seed if 961 <= u <= 970 else 100},{u}" for u in range(1, 977))]
            (folder / "progress.csv").write_text("\n".join(rows) + "\n")
    script.main(["--cat", str(tmp_path), "--out", str(tmp_path / "table.md")])
    table = (tmp_path / "table.md").read_text()
    assert "| centipede-six |" in table and "| 10 | " in table  # CAT's seed 0 is its window's 10
    assert "10 / 11 / 12 / 13 / 14 | 12 |" in table  # the five seeds and their mean
    assert table == capsys.readouterr().out


def test_teacher_screen_report_sets_both_teachers_and_cat_side_by_side_with_cat_s_estimator(registry, tmp_path):
    from miktcli.registry.runs import open_run

    script = load_script("teacher_screen_report")
    steps = 1_000_000 // 2048 + 500  # past CAT's last window
    folders = {}
    for name, level in (("new", 4000.0), ("old", 3000.0)):
        folders[name] = []
        for seed in (0, 1):
            rows = [{"episode_return_iter": level + seed} for _ in range(steps)]
            run_id = fake_run(registry, "centipede-eight", "mikt", seed, [level] * steps, level, per_row=rows,
                              teachers=("centipede-four", f"six-{name}"))
            run = open_run(registry, run_id)
            run.save_card(result={**run.card.result, "handover": {"with_teachers": {"return_mean": level},
                                                                  "without_teachers": {"return_mean": level / 2}}})
            folders[name].append(run.path)
    out = tmp_path / "pair.md"
    script.main(["--new", *map(str, folders["new"]), "--old", *map(str, folders["old"]), "--out", str(out)])
    table = out.read_text()
    assert "| **new six teacher: seed mean** | **4,000** | **4,000** | **4,000** | 4,000 → 2,000 (50 %) |" in table
    assert "| **six@v2: seed mean** | **3,000** | **3,000** | **3,000** |" in table
    assert "| CAT (1 seed) | 3,084 | 4,219 | 4,909 | |" in table
    assert "New six teacher minus six@v2 (seed means): +1,000, +1,000, +1,000; new six teacher minus CAT: +916, " \
        "-218, -908." in table
    # another screen names what it changed; PPO from scratch has no CAT row and no hand-over
    script.main(["--new", *map(str, folders["new"]), "--old", *map(str, folders["old"]), "--out", str(out),
                 "--new-label", "zero contacts", "--old-label", "live contacts", "--intro", "PPO.", "--no-cat"])
    table = out.read_text()
    assert table.splitlines()[1].startswith("PPO. Mean per-update return")
    assert "| **zero contacts: seed mean** | **4,000** |" in table and "CAT" not in table.split("\n", 2)[2]
    assert "Zero contacts minus live contacts (seed means): +1,000, +1,000, +1,000." in table


def test_study_scaling_grids_are_valid_grids_with_and_without_seeds_together(tmp_path):
    from miktcli.studies.grid import load_grid

    scaling = load_script("study_scaling")
    for together in (False, True):
        path = tmp_path / f"{together}.toml"
        path.write_text(scaling.grid_text(5, 2048, ("centipede-four", "centipede-six"), together))
        grid = load_grid(path)
        assert grid.seeds_together is together and grid.seeds == [0, 1, 2, 3, 4]
        assert [pair.to for pair in grid.pairs] == ["centipede-four", "centipede-six"]


@pytest.mark.slow
def test_throughput_quick_run_writes_its_tables_and_figures(tmp_path):
    pytest.importorskip("stable_baselines3", reason="the SB3 side needs pip install -e '.[bench]'")
    throughput = load_script("throughput")
    res = throughput.main(["--quick", "--no-whole-process", "--out", str(tmp_path)])
    saved = json.loads((tmp_path / "throughput.json").read_text())
    assert saved["quick"] and saved["in_process"]["engine"]["lean_env"]
    assert set(saved["ratios"]) == {"rollout_vs_physics", "rollout_vs_physics_same_steps", "ppo_vs_sb3",
                                    "ppo_by_hand_vs_sb3"}
    assert all(v > 0 for v in saved["ratios"].values())
    page = (tmp_path / "throughput.md").read_text()
    assert saved["date"] in page and "python benchmarks/throughput.py --quick" in page
    assert "centipede-eight env step" in page and "MIKT 2 teachers" in page
    # the whole-process part: the report's ratios from timed commands (cheap stand-ins here)
    timed = throughput.whole_process({"a": [sys.executable, "-c", "pass"]}, 2, env=None)
    assert timed["a"]["wall_s"] == min(timed["a"]["all_s"]) and len(timed["a"]["all_s"]) == 2
    names = throughput.process_commands(30720, 20480)
    res["whole_process"] = {name: {"command": " ".join(c), "wall_s": 10.0 + i} for i, (name, c) in
                            enumerate(names.items())}
    res["seeds_together"] = {"seeds": 5, "steps_per_seed": 20480, "together_s": 10.0, "separate_s": 16.0}
    ratios = throughput.ratios(res)
    assert ratios["teacher_vs_sb3_script"] == 11.0 / 10.0 and ratios["two_teachers_vs_ppo"] == 15.0 / 12.0
    assert ratios["one_teacher_vs_ppo_autograd"] == 14.0 / 13.0  # the transfers against autograd's PPO too
    assert ratios["seeds_together_vs_separate"] == 1.6
    page = throughput.markdown({**res, "ratios": ratios})
    assert "two-teacher transfer" in page and "5 seeds × 20,480 steps" in page
    assert "gradient by hand" in page and "with autograd's update" in page and "by hand µs" in page
    update = throughput.together_update(2, 1, n_steps=128)
    assert update["seeds"] == 2
    assert update["together_ms_per_seed_minibatch"] > 0 and update["separate_ms_per_seed_minibatch"] > 0
    res["seeds_together"]["update"] = update
    page = throughput.markdown({**res, "ratios": ratios})
    assert "the update alone, in process: 2 two-teacher centipede-eight agents" in page


def test_loss_bits_finds_no_difference_on_the_same_code_and_names_a_changed_tensor(tmp_path, capsys):
    loss_bits = load_script("loss_bits")
    saved = tmp_path / "ref.pt"
    assert loss_bits.main(["save", str(saved)]) == 0
    assert loss_bits.main(["check", str(saved)]) == 0
    reference = torch.load(saved)
    reference["m2"]["loss"] = reference["m2"]["loss"] + 1.0
    torch.save(reference, saved)
    assert loss_bits.main(["check", str(saved)]) == 1
    assert "differs: m2 loss" in capsys.readouterr().out


def test_aggregate_report_normalises_by_random_and_the_baseline_per_target(registry, tmp_path):
    from miktcli.studies.grid import load_grid

    grid_file, study = tmp_path / "agg.toml", tmp_path / "agg"
    grid_file.write_text(GRID.format(
        name="agg", seeds="[0, 1]", baseline="vpg", extra='[[methods]]\nname = "vpg"\nmethod = "vpg"\n',
        pairs='[[pairs]]\nfrom = ["four"]\nto = "hopper"\n[[pairs]]\nfrom = ["four"]\nto = "ant"\n'))
    cells = {  # final returns: vpg hopper 10, 30 (R_vpg 20), ant 20, 40 (R_vpg 30); mikt twice to thrice that
        "->hopper|vpg|0": fake_run(registry, "hopper", "vpg", 0, [0, 0, 10], 1),
        "->hopper|vpg|1": fake_run(registry, "hopper", "vpg", 1, [0, 0, 30], 1),
        "->ant|vpg|0": fake_run(registry, "ant", "vpg", 0, [0, 0, 20], 1),
        "->ant|vpg|1": fake_run(registry, "ant", "vpg", 1, [0, 0, 40], 1),
        "four>hopper|mikt|0": fake_run(registry, "hopper", "mikt", 0, [0, 0, 40], 1),
        "four>hopper|mikt|1": fake_run(registry, "hopper", "mikt", 1, [0, 0, 60], 1),
        "four>ant|mikt|0": fake_run(registry, "ant", "mikt", 0, [0, 0, 50], 1),
        "four>ant|mikt|1": fake_run(registry, "ant", "mikt", 1, [0, 0, 70], 1),
    }
    study.mkdir()
    (study / "state.json").write_text(json.dumps(cells))
    for run_id in cells.values():
        shutil.copytree(registry / "runs" / run_id, study / "runs" / run_id)
    path = load_script("aggregate_report").aggregate_report(study, load_grid(grid_file), {"hopper": 0.0, "ant": 5.0},
                                                            n_resamples=500)
    text = path.read_text()
    final = text.split("## Final return")[1].split("## Mean over training")[0]
    # normalised: hopper mikt 2, 3, vpg 0.5, 1.5; ant (random 5) mikt 1.8, 2.6, vpg 0.6, 1.4. IQM of the four
    # pooled: the middle two (2, 2.6 → 2.3; 0.6, 1.4 → 1); mikt beats every vpg run
    assert "| mikt | 4 | 2 | 2.30 [" in final and "| vpg | 4 | 2 | 1.00 [" in final
    assert "| mikt vs vpg | 1.00 [1.00, 1.00] | 2 |" in final
    assert "| four → ant | 2.20 | 1.00 |" in final  # two runs: nothing trimmed
    assert "| ant | 5.0 | — | 30 | 2 |" in text  # no initial-policy returns given: shown as missing
    assert (study / "aggregate-profile.png").read_bytes()[:4] == b"\x89PNG"


def test_multi_teacher_report_against_cat_and_across_studies_by_hand(registry, tmp_path):
    from miktcli.studies.grid import load_grid
    from miktcli.studies.reference import load_reference

    two_grid, one_grid, cat_file = tmp_path / "two.toml", tmp_path / "one.toml", tmp_path / "cat.toml"
    two_grid.write_text(
        'name = "two"\nsteps = 12288\nseeds = [0, 1]\nmarks = [4096, 8192, 12288]\nbaseline = "vpg"\n'
        '[[pairs]]\nfrom = ["a", "b"]\nto = "hopper"\n[[pairs]]\nfrom = ["a", "b"]\nto = "ant"\n'
        '[[methods]]\nname = "mikt"\nmethod = "mikt"\n[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    one_grid.write_text(GRID.format(  # seeds 0-2: seed 2 is not on the two-teacher grid's seeds, left out
        name="one", seeds="[0, 1, 2]", baseline="mikt", extra="",
        pairs='[[pairs]]\nfrom = ["a"]\nto = "hopper"\n[[pairs]]\nfrom = ["c"]\nto = "walker"\n'))
    cat_file.write_text('estimator = "by hand"\nwindows = [[2048, 4096], [10240, 12288]]\nhand_over_before = 4096\n'
                        'ramp_marks = [4096, 12288]\n'
                        '[[runs]]\nteachers = ["a", "b"]\nto = "hopper"\nreturns = [10, 50]\n'
                        'hand_over = { drop = 8192, p_pi = 0.9, p_vf = 0.8, before = 30, after = 20 }\n'
                        'ramp = { p_pi = [0.5, 0.6], p_vf = [0.4, 0.5] }\n')
    def rows(per_iteration, p_pi, p_vf):  # teachers for four iterations, dropped for the last two
        return [{"episode_return_iter": r, "teacher_active": float(i < 4), "p_pi_0": p_pi, "p_vf_0": p_vf}
                for i, r in enumerate(per_iteration)]

    two = {
        "a+b>hopper|mikt|0": fake_run(registry, "hopper", "mikt", 0, [0, 20, 30, 40, 50, 60], 1,
                                      per_row=rows([10, 20, 30, 40, 50, 60], 0.8, 0.9)),
        "a+b>hopper|mikt|1": fake_run(registry, "hopper", "mikt", 1, [0, 10, 30, 20, 40, 80], 1,
                                      per_row=rows([30, 40, float("nan"), 60, 70, 80], 0.7, 0.6)),
        "a+b>ant|mikt|0": fake_run(registry, "ant", "mikt", 0, [0, 40, 10, 20, 30, 30], 1,
                                   per_row=[{"episode_return_iter": 0}] * 6),  # falls between 4096 and 8192;
        # seed 1 unfinished; it logs no teacher_active: no hand-over
        "->hopper|vpg|0": fake_run(registry, "hopper", "vpg", 0, [20] * 6, 1),
        "->hopper|vpg|1": fake_run(registry, "hopper", "vpg", 1, [40] * 6, 1),
        "->ant|vpg|0": fake_run(registry, "ant", "vpg", 0, [10] * 6, 1),
        "->ant|vpg|1": fake_run(registry, "ant", "vpg", 1, [30] * 6, 1),
    }
    one = {
        "a>hopper|mikt|0": fake_run(registry, "hopper", "mikt", 0, [30] * 6, 1),
        "a>hopper|mikt|1": fake_run(registry, "hopper", "mikt", 1, [60] * 6, 1),
        "a>hopper|mikt|2": fake_run(registry, "hopper", "mikt", 2, [999] * 6, 1),
        "c>walker|mikt|0": fake_run(registry, "walker", "mikt", 0, [999] * 6, 1),  # not a two-teacher target
    }
    for name, cells in (("two", two), ("one", one)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "state.json").write_text(json.dumps(cells))
        for run_id in cells.values():
            shutil.copytree(registry / "runs" / run_id, tmp_path / name / "runs" / run_id)
    shutil.rmtree(registry)  # the report needs the snapshots only

    script = load_script("multi_teacher_report")
    path = script.report(tmp_path / "two", load_grid(two_grid), tmp_path / "one", load_grid(one_grid),
                         load_reference(cat_file), {"hopper": 0.0, "ant": 0.0}, "by hand", n_resamples=500,
                         fall=(4096, 8192))
    text = path.read_text()
    rows = [line for line in text.splitlines() if line.startswith("| a+b → ")]
    # CAT's estimator: iterations 1-2 (15, 35) and 5-6 (55, 75), the NaN iteration of seed 1 outside both
    assert rows[0] == "| a+b → hopper | 2 | 25 ± 14 | 10 | 65 ± 14 | 50 |"
    assert rows[1] == "| a+b → ant | 1 | 0 | — | 0 | — |"
    # the study's estimator at 4096, 8192, 12288; the mean curve 15 → 30 over (15, 30, 30)
    assert rows[2] == "| a+b → hopper | 2 | 15 ± 7 | 30 ± 14 | 70 ± 14 | 50 | +20 | yes | 15 → 30 (no fall; 15) |"
    assert rows[3] == "| a+b → ant | 1 | 40 | 20 | 30 | — | — | — | 40 → 20 (falls; 10) |"
    # the hand-over: the last coupled iteration is at 8192 steps (returns 40, 20), then (50, 60) and (40, 80)
    assert "| a+b → hopper | 2 | 8,192 | 0.70 ± 0.14 | 30 ± 14 | 45 ± 7 | 70 ± 14 | 1 ± 0 |" in text
    assert "| a+b → ant | 0 | — | — | — | — | — | — |" in text
    # the weights during the ramp: each branch's one layer, constant per seed (0.8, 0.7 and 0.9, 0.6)
    assert "| a+b → hopper | π | 2 | 0.75 ± 0.07 | 0.50 | 0.75 ± 0.07 | 0.60 |" in text
    assert "| a+b → hopper | V | 2 | 0.75 ± 0.21 | 0.40 | 0.75 ± 0.21 | 0.50 |" in text
    assert "| a+b → ant | π | 1 | — | — | — | — |" in text
    # across the drop as CAT measures it: before = iterations 3-4 (35; seed 1: 60, its NaN skipped), after =
    # iterations 5-6 (55; 75); p is each branch's layer mean (one layer here)
    assert ("| a+b → hopper | 2 | 0.75 ± 0.07 / 0.75 ± 0.21 | 0.90 / 0.80 | 48 ± 18 → 65 ± 14 | +18 ± 4 | 0 of 2 | "
            "30 → 20 | -10 |") in text
    assert "Reaches CAT on **1 of 1** pairs" in text and "falls between 0.004096M and 0.008192M on 1" in text
    assert "| hopper | 0.0 | 30 | 30 | 2 |" in text and "| ant | 0.0 | 20 | 20 | 2 |" in text
    final = text.split("### Final return")[1].split("### Mean over training")[0]
    # normalised final: two-teacher hopper 2, 2.67 and ant 1.5 (IQM of 3 trims nothing: 2.06); one-teacher
    # hopper 1, 2; vpg 0.67, 1.33 and 0.5, 1.5 (IQM: the middle two, 1.00)
    assert "| two-teacher mikt | 3 | 2 | hopper, ant | 2.06 [" in final
    assert "| one-teacher mikt | 2 | 1 | hopper | 1.50 [" in final
    assert "| vpg (from scratch) | 4 | 2 | hopper, ant | 1.00 [" in final
    # per target: hopper (2, 2.67) against (1, 2) is 3.5 of 4; against vpg, hopper 1 and ant 0.75
    versus = {line.split(" | ")[0][2:]: line for line in final.splitlines() if " vs " in line}
    assert versus["two-teacher mikt vs one-teacher mikt"].startswith("| two-teacher mikt vs one-teacher mikt | 0.88 [")
    assert versus["two-teacher mikt vs one-teacher mikt"].endswith("| hopper |")
    assert versus["two-teacher mikt vs vpg (from scratch)"].endswith("] | hopper, ant |")
    assert "| two-teacher mikt vs vpg (from scratch) | 0.88 [" in final
    assert "| one-teacher mikt vs vpg (from scratch) | 0.75 [" in final  # 1 beats 0.67, loses to 1.33; 2 beats both
    assert (tmp_path / "two" / "against-cat-profile.png").read_bytes()[:4] == b"\x89PNG"
    # a screening whose baseline is a transfer method: the sections against CAT, none across studies
    screen = tmp_path / "screen.toml"
    screen.write_text(two_grid.read_text().split("[[methods]]")[0].replace('baseline = "vpg"', 'baseline = "mikt"')
                      + '[[methods]]\nname = "mikt"\nmethod = "mikt"\n')
    path = script.report(tmp_path / "two", load_grid(screen), tmp_path / "one", load_grid(one_grid),
                         load_reference(cat_file), {}, "by hand", out=tmp_path / "screen.md")
    text = path.read_text()
    assert text.startswith("# two: `mikt` against CAT") and "is not PPO from scratch" in text
    assert "| a+b → hopper | π | 2 | 0.75 ± 0.07 | 0.50 | 0.75 ± 0.07 | 0.60 |" in text
    assert "## Across studies" not in text and not (tmp_path / "screen-profile.png").exists()


def test_a_malformed_reference_file_is_a_one_line_error(tmp_path):
    from miktcli.errors import MiktError
    from miktcli.studies.reference import load_reference

    bad = tmp_path / "cat.toml"
    bad.write_text('windows = [[1, 2]]\n[[runs]]\nteachers = ["a"]\nto = "x"\nreturns = [1, 2]\n')
    with pytest.raises(MiktError, match="one return per window"):
        load_reference(bad)
    bad.write_text('windows = [[1, 2]]\n[[runs]]\nteachers = ["a"]\nto = "x"\nreturns = [1]\n'
                   'hand_over = { drop = 2, p_pi = 0.9, p_vf = 0.9, before = 1, after = 2 }\n')
    with pytest.raises(MiktError, match="no hand_over_before"):
        load_reference(bad)
    bad.write_text('windows = [[1, 2]]\nramp_marks = [1, 2]\n[[runs]]\nteachers = ["a"]\nto = "x"\nreturns = [1]\n'
                   'ramp = { p_pi = [0.5], p_vf = [0.5, 0.6] }\n')
    with pytest.raises(MiktError, match="one student weight per ramp_marks"):
        load_reference(bad)
    bad.write_text("windows = [")
    with pytest.raises(MiktError, match="not a reference file"):
        load_reference(bad)
    with pytest.raises(MiktError, match="cannot be read"):
        load_reference(tmp_path / "absent.toml")


@pytest.mark.slow
def test_paired_numerics_pairs_seeds_and_reads_each_run_at_the_mark(tmp_path):
    out = tmp_path / "paired.json"
    subprocess.run([sys.executable, str(BENCHMARKS / "paired_numerics.py"), "--seeds", "0-1", "--mark", "2048",
                    "--base", "teacher train hopper --steps 8192", "--a=--no-compile", "--b=--no-compile",
                    "--out", str(out)], check=True, capture_output=True, timeout=600)
    summary = json.loads(out.read_text())
    assert [r["seed"] for r in summary["rows"]] == [0, 1]
    # the same command twice: the same bits, so no difference and no lower seed
    assert all(r["a"] == r["b"] for r in summary["rows"]) and summary["a_lower_on"] == 0
    assert summary["rows"][0]["a"] != summary["rows"][1]["a"]  # two seeds, two runs


def _timed_run(folder: Path, run_id: str, update_times: list[float], status: str = "completed") -> None:
    """A MIKT run folder with only what update_steadiness reads: its card and one timing row per iteration."""
    folder.mkdir(parents=True)
    card = {"run_id": run_id, "status": status, "env": "centipede-six", "method": "mikt", "seed": 0,
            "total_steps": 2048 * len(update_times),
            "teachers": [{"name": "centipede-four", "version": 2}, {"name": "ant", "version": 2}],
            "config": {"ppo": {"n_steps": 2048, "num_envs": 1},
                       "options": {"ramp_start": 0.45, "drop_teacher_at": 0.9}}, "result": {}}
    (folder / "run.json").write_text(json.dumps(card))
    rows = [{"iteration": i + 1, "steps": 2048 * (i + 1), "time_rollout": 1.0, "time_update": u}
            for i, u in enumerate(update_times)]
    (folder / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))


def test_update_steadiness_reports_each_phase_s_spread_of_the_update_time(tmp_path, capsys, monkeypatch):
    steadiness = load_script("update_steadiness")
    runs = tmp_path / "runs"
    # 200 iterations: independent 1-90, ramp 91-170, hand-over window 171-180, teacher-free 181-200. The slowed
    # run's update triples from iteration 40 on, inside its first phase, as the slowed multi-cat runs' did.
    _timed_run(runs / "run1", "run1", [0.5] * 200)
    _timed_run(runs / "run2", "run2", [0.5] * 39 + [1.5] * 161)
    _timed_run(runs / "run3", "run3", [0.5] * 200, status="interrupted")
    monkeypatch.setattr(sys, "argv", ["update_steadiness.py", str(runs), "--json", str(tmp_path / "out.json")])
    steadiness.main()
    out = capsys.readouterr().out
    rows = {r["run"]: r["spread"] for r in json.loads((tmp_path / "out.json").read_text())}
    assert set(rows) == {"run1", "run2"}  # completed runs only
    # the hand-over window's 10 iterations are fewer than one rolling median: no figure for it
    assert rows["run1"] == {"independent": 1.0, "ramp": 1.0, "teacher-free": 1.0}
    assert rows["run2"]["independent"] == 3.0 and rows["run2"]["ramp"] == 1.0
    assert "2 completed runs; highest spread 3.00x" in out
