"""Interrupting and resuming: a killed run resumes, a run is never trained twice at once, resume refuses what it
would ignore, and a resumed run ends exactly like one never interrupted."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from helpers import interrupted, mikt, runner, runs
from miktcli.cli.app import app
from miktcli.registry.runs import open_run

# locks and liveness -------------------------------------------------------------------------------------------------

@pytest.mark.slow  # process-level: runs mikt in a subprocess
def test_sigkill_leaves_a_stale_run_that_resumes(registry, tmp_path):
    env = {**os.environ, "MIKT_REGISTRY": str(registry)}
    proc = subprocess.Popen([sys.executable, "-m", "miktcli", "teacher", "train", "hopper", "--steps", "40960"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    checkpoint = registry / "runs" / "run1" / "checkpoint.safetensors"
    deadline = time.monotonic() + 120
    while not checkpoint.exists() and time.monotonic() < deadline:
        time.sleep(0.2)
    assert checkpoint.exists()
    assert runs(registry)[0]["status"] == "running"  # alive, holding its lock
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert runs(registry)[0]["status"] == "stale"
    assert "stale" in mikt("runs").output


def test_a_run_being_trained_cannot_be_resumed_twice(registry):
    from miktcli.registry.runs import RunLock, open_run

    r = runner.invoke(app, ["teacher", "train", "hopper", "--steps", "6144"], catch_exceptions=False)
    assert r.exit_code == 0
    run_dir = registry / "runs" / "run1"
    card = json.loads((run_dir / "run.json").read_text())
    card["status"] = "interrupted"
    (run_dir / "run.json").write_text(json.dumps(card))
    lock = RunLock(open_run(registry, "run1")).acquire()  # another trainer holds it
    try:
        r = mikt("teacher", "train", "--resume", "run1", code=1)
        assert f"run1 is being trained by pid {os.getpid()}" in r.output
    finally:
        lock.release()


# what resume refuses ------------------------------------------------------------------------------------------------

def test_a_checkpoint_from_another_run_is_refused(two_vpg_runs, registry):
    interrupted(open_run(registry, "run1"))
    shutil.copy(two_vpg_runs / "run2" / "checkpoint.safetensors", two_vpg_runs / "run1" / "checkpoint.safetensors")
    r = mikt("transfer", "--resume", "run1", code=1)
    assert "belongs to run2, not to run1" in r.output


@pytest.mark.parametrize("extra", [("--steps", 5), ("--method", "mlpp"), ("--seed", 3), ("--to", "ant"),
                                   ("--no-mi",), ("--num-envs", 2)])
def test_resume_refuses_options_it_would_ignore(registry, extra):
    r = mikt("transfer", "--resume", "run1", *extra, code=2)
    assert "cannot be combined with --resume" in r.output


def test_teacher_resume_refuses_an_environment_argument(registry):
    assert "cannot be combined with --resume" in mikt("teacher", "train", "ant", "--resume", "run1", code=2).output


# resume is exact ----------------------------------------------------------------------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("env", ["hopper", "centipede-four"])
def test_a_resumed_run_ends_exactly_like_an_uninterrupted_one(registry, ctrl_c_at_second_update, env):
    from miktcli.registry.runs import open_run

    mikt("teacher", "train", env, "--steps", 6144, "--name", "resumed", code=1)  # Ctrl-C in the 2nd update
    ctrl_c_at_second_update()  # from here on training runs normally
    mikt("teacher", "train", "--resume", "run1")
    mikt("teacher", "train", env, "--steps", 6144, "--name", "straight")
    keys = ("return_mean", "length_mean", "episodes", "loss_policy", "loss_value", "approx_kl")
    resumed = [[m[k] for k in keys] for m in open_run(registry, "run1").read_metrics()]
    straight = [[m[k] for k in keys] for m in open_run(registry, "run2").read_metrics()]
    assert len(straight) == 3 and straight == resumed
