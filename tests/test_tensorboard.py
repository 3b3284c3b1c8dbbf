"""Runs write TensorBoard event files that TensorBoard itself reads; studies group them pair / method / seed."""

import json

import pytest
from typer.testing import CliRunner

from miktcli.cli.app import app
from miktcli.registry.tensorboard import crc32c, read_scalars

runner = CliRunner()


def test_crc32c_known_answer():
    assert crc32c(b"123456789") == 0xE3069283  # the CRC-32C check value


def test_a_run_folder_holds_events_matching_its_metrics(registry):
    from miktcli.registry.runs import open_run

    assert runner.invoke(app, ["teacher", "train", "hopper", "--steps", "4096"]).exit_code == 0
    run = open_run(registry, "run1")
    scalars = read_scalars(run.events_path)  # checks every record's CRCs
    rows = run.read_metrics()
    by_tag = {(step, tag): value for step, tag, value in scalars}
    for row in rows:
        assert by_tag[(row["steps"], "episode/return_mean")] == pytest.approx(row["return_mean"], rel=1e-6)
        assert by_tag[(row["steps"], "loss/policy")] == pytest.approx(row["loss_policy"], rel=1e-6, abs=1e-9)
        assert (row["steps"], "ppo/approx_kl") in by_tag and (row["steps"], "time/steps_per_sec") in by_tag


@pytest.mark.slow
def test_tensorboard_reads_runs_and_study_trees(registry, tmp_path):
    event_accumulator = pytest.importorskip("tensorboard.backend.event_processing.event_accumulator")
    assert runner.invoke(app, ["teacher", "train", "hopper", "--steps", "2048", "--name", "tiny"]).exit_code == 0
    grid = tmp_path / "g.toml"
    grid.write_text('name = "g"\nsteps = 4096\nseeds = [0]\neval_episodes = 1\n'
                    '[[pairs]]\nfrom = ["tiny"]\nto = "centipede-four"\n'
                    '[[methods]]\nname = "mikt"\nmethod = "mikt"\n[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    out = tmp_path / "study"
    assert runner.invoke(app, ["study", str(grid), "--out", str(out)]).exit_code == 0
    for folder in (registry / "runs" / "run2", out / "tensorboard" / "tiny-to-centipede-four" / "mikt" / "seed0"):
        acc = event_accumulator.EventAccumulator(str(folder))
        acc.Reload()
        tags = acc.Tags()["scalars"]
        assert {"episode/return_mean", "loss/mi", "mixing/p_pi_0", "mikt/coupling_scale"} <= set(tags)
        assert [e.step for e in acc.Scalars("episode/return_mean")] == [2048, 4096]
    vpg = out / "tensorboard" / "tiny-to-centipede-four" / "vpg" / "seed0"
    assert any(p.name.startswith("events.out.tfevents") for p in vpg.iterdir())


def test_resume_rewrites_events_without_duplicates(registry, ctrl_c_at_second_update):
    from miktcli.registry.runs import open_run

    assert runner.invoke(app, ["teacher", "train", "hopper", "--steps", "6144"]).exit_code == 1
    ctrl_c_at_second_update()
    assert runner.invoke(app, ["teacher", "train", "--resume", "run1"]).exit_code == 0
    steps = [s for s, tag, _ in read_scalars(open_run(registry, "run1").events_path) if tag == "episode/return_mean"]
    assert steps == [2048, 4096, 6144]
    assert json.loads(runner.invoke(app, ["runs", "--json"]).stdout)[0]["status"] == "completed"
