"""Hostile and clumsy input: each root cause of issue 14 reproduced, and handled."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest
import torch
from safetensors.torch import load as st_load

from helpers import mikt, rewrite_teacher, runner, runs, spec_dir
from miktcli.cli.app import app


@pytest.fixture()
def teacher(registry):
    mikt("teacher", "train", "hopper", "--steps", 2048, "--name", "tiny")
    return registry / "teachers" / "tiny" / "v1.safetensors"


# 1. outside text never acts on the terminal --------------------------------------------------------------

def test_markup_in_arguments_is_shown_literally(registry):
    r = mikt("teacher", "show", "[/x]", code=1)
    assert "[/x]" in r.output
    r = mikt("eval", "[b]hi[/b]", code=1)
    assert "'[b]hi[/b]'" in r.output
    mikt("transfer", "--from", "[/x]", "--to", "hopper", code=1)


def test_markup_and_escape_codes_in_cards_are_inert(teacher, registry):
    rewrite_teacher(teacher, {"env": "hopper[/oops]\x1b[2J"})
    r = mikt("teacher", "list")
    assert "[/oops]" in r.output and "\x1b" not in r.output and "\\x1b[2J" in r.output
    card = registry / "runs" / "run1" / "run.json"
    data = json.loads(card.read_text())
    data["command"] = "[/oops] \x1b[2J"
    card.write_text(json.dumps(data))
    assert "\x1b" not in mikt("inspect", "run1").output
    assert "run1" in mikt("runs").output


def test_the_error_printer_cannot_throw(monkeypatch):
    from miktcli.cli import console

    def broken(*args, **kwargs):
        raise RuntimeError("console is gone")

    monkeypatch.setattr(console.err, "print", broken)
    console.print_error("bad [/x] \x1b[2J", "hint")  # falls back to plain writes, escaping controls


# 2. locks and liveness ------------------------------------------------------------------------------------

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


# 3. validation before any work ----------------------------------------------------------------------------

def test_bad_seed_and_name_fail_before_a_run_exists(registry):
    mikt("teacher", "train", "hopper", "--seed", -5, code=2)
    mikt("teacher", "train", "hopper", "--name", "x" * 300, code=1)
    mikt("transfer", "--to", "hopper", "--method", "vpg", "--seed", -1, code=2)
    assert runs(registry) == []


def test_an_unwritable_registry_is_found_before_training(registry):
    registry.mkdir(parents=True)
    (registry / "teachers").write_text("a file where the teachers folder belongs")
    r = mikt("teacher", "train", "hopper", "--steps", 2048, code=1)
    assert "not writable" in r.output
    assert runs(registry) == []


def test_a_failure_after_training_marks_the_run_failed(registry, monkeypatch):
    import miktcli.workflows.teacher as teacher_workflow

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device", str(registry / "teachers"))

    monkeypatch.setattr(teacher_workflow, "publish_teacher_from_job", broken)
    r = mikt("teacher", "train", "hopper", "--steps", 2048, code=1)
    assert "No space left on device" in r.output and "internal error" not in r.output
    assert "free some space" in r.output
    card = runs(registry)[0]
    assert card["status"] == "failed" and "No space left" in card["error"]


# 4. references are never paths ----------------------------------------------------------------------------

@pytest.mark.parametrize("ref", ["../x@v1", "/etc/passwd", "a/../../b", "..", "./tiny"])
def test_teacher_refs_are_names_not_paths(teacher, ref):
    assert "invalid teacher name" in mikt("teacher", "show", ref, code=1).output
    mikt("eval", ref, code=1)
    mikt("inspect", ref, code=1)


# 5. well-formed but wrong files -----------------------------------------------------------------------------

def test_extra_or_missing_tensors_and_misplaced_cards_are_refused(teacher):
    tensors = st_load(teacher.read_bytes())
    original = dict(tensors)
    rewrite_teacher(teacher, tensors={**tensors, "surprise": torch.zeros(3)})
    assert "unexpected tensor 'surprise'" in mikt("eval", "tiny", "--episodes", 1, code=1).output
    rewrite_teacher(teacher, tensors={k: v for k, v in original.items() if k != "log_std"})
    assert "tensor 'log_std' is missing" in mikt("eval", "tiny", "--episodes", 1, code=1).output
    rewrite_teacher(teacher, tensors=original, update={"name": "other"})
    assert "stored as tiny@v1" in mikt("teacher", "show", "tiny", code=1).output
    rewrite_teacher(teacher, tensors=original, update={"env_spec": {"obs_dim": 97, "act_dim": 10}})
    assert "its env 'hopper' has obs 97" in mikt("teacher", "show", "tiny", code=1).output


@pytest.mark.parametrize("drop", ["reward_scaler.moments", "optim.exp_avg", "progress.global_step"])
def test_checkpoints_missing_state_are_refused_on_resume(registry, drop):
    from miktcli.registry.runs import open_run

    mikt("teacher", "train", "hopper", "--steps", 6144, "--name", "t")
    run = open_run(registry, "run1")
    ckpt, tensors = run.load_checkpoint()
    progress = dict(ckpt.progress)
    if drop.startswith("progress."):
        progress.pop(drop.split(".", 1)[1])
    else:
        tensors.pop(drop)
    run.save_checkpoint(tensors, ckpt.iteration, ckpt.steps, progress)
    run.save_card(status="interrupted")
    r = mikt("teacher", "train", "--resume", "run1", code=1)
    assert "checkpoint.safetensors" in r.output and drop.split(".")[-1] in r.output
    assert runs(registry)[0]["status"] == "failed"


# 6. damaged run files -----------------------------------------------------------------------------------------

def test_damaged_metrics_lines_are_skipped_and_counted(registry):
    mikt("teacher", "train", "hopper", "--steps", 4096)
    path = registry / "runs" / "run1" / "metrics.jsonl"
    with path.open("ab") as f:
        f.write(b'{"iteration": "x"}\n[1, 2]\n\xff\xfe not utf-8\n{"iteration": 3}\n{"steps": 1, "iteration": 3, '
                b'"return_mean": "text"}\n' + b"[" * 100_000 + b"\n")
    r = mikt("inspect", "run1", "--curve")
    assert "skipped 6 damaged line(s)" in r.output
    data = json.loads(mikt("inspect", "run1", "--json").stdout)
    assert [m["iteration"] for m in data["metrics"]] == [1, 2]


def test_a_damaged_run_card_is_listed_not_hidden(registry):
    mikt("teacher", "train", "hopper", "--steps", 2048)
    (registry / "runs" / "run1" / "run.json").write_text('{"run_id": "run1", "seed": "x"}')
    r = mikt("runs")
    assert "damaged" in r.output
    listed = json.loads(mikt("runs", "--json").stdout)
    assert listed[0]["run_id"] == "run1" and "field '" in listed[0]["error"]


# 7. OS errors are user errors ---------------------------------------------------------------------------------

def test_registry_pointing_at_a_file_and_study_out_on_a_file(tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("x")
    r = mikt("teacher", "train", "hopper", "--steps", 2048, "--registry", afile, code=1)
    assert "internal error" not in r.output
    grid = tmp_path / "g.toml"
    grid.write_text('name = "x"\nsteps = 2048\nseeds = [0]\n[[pairs]]\nfrom = ["a"]\nto = "hopper"\n'
                    '[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    r = mikt("study", grid, "--out", afile, "--registry", tmp_path / "reg", code=1)
    assert "internal error" not in r.output


# 8. spec files ----------------------------------------------------------------------------------------------


def test_one_bad_spec_does_not_hide_the_good_ones(tmp_path, monkeypatch):
    spec_dir(tmp_path, monkeypatch, broken='name = "broken"\nfamily = "centipede"\n')
    r = runner.invoke(app, ["envs"])
    assert r.exit_code == 1
    assert "hopper" in r.stdout and "centipede-four" in r.stdout
    assert "broken.toml" in r.output


@pytest.mark.parametrize(("body", "message"), [
    ('family = "centipede"\nlegs = 100000\nobs_dim = 1\nact_dim = 1\n', "less than or equal to 40"),
    ('family = "gymnasium"\nid = "os:system"\nobs_dim = 1\nact_dim = 1\n', "refused"),
    ('family = "gymnasium"\nid = "no version"\nobs_dim = 1\nact_dim = 1\n', "expected a registered gymnasium"),
    ('family = "gymnasium"\nid = "evil.module:Env-v0"\nobs_dim = 1\nact_dim = 1\n', "refused"),
])
def test_dangerous_or_absurd_specs_are_refused(tmp_path, monkeypatch, body, message):
    spec_dir(tmp_path, monkeypatch, bad=f'name = "bad"\n{body}')
    assert message in mikt("envs", "show", "bad", code=1).output


def test_discrete_and_non_mujoco_envs_are_refused(tmp_path, monkeypatch):
    spec_dir(tmp_path, monkeypatch, cart='name = "cart"\nfamily = "gymnasium"\nid = "CartPole-v1"\n'
                                         'obs_dim = 4\nact_dim = 1\n',
             pend='name = "pend"\nfamily = "gymnasium"\nid = "Pendulum-v1"\nobs_dim = 3\nact_dim = 1\n',
             kw='name = "kw"\nfamily = "gymnasium"\nid = "Hopper-v5"\nobs_dim = 11\nact_dim = 3\n'
                '[kwargs]\nfrobnicate = 3\n')
    assert "not a continuous vector" in mikt("envs", "show", "cart", code=1).output
    assert "not a MuJoCo environment" in mikt("envs", "show", "pend", code=1).output
    assert "fails with these kwargs" in mikt("envs", "show", "kw", code=1).output


# 10. names -------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["", "last", "run3", "latest", "Bad", "a/b", ".hidden"])
def test_reserved_and_bad_names_are_refused(registry, name):
    mikt("teacher", "train", "hopper", "--steps", 2048, "--name", name, code=1)
    assert runs(registry) == []


# 11. resume is exact -----------------------------------------------------------------------------------------

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
