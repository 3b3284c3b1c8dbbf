"""Damaged, tampered, moved or well-formed but wrong files (teachers, checkpoints, run cards, metrics,
students): each is refused or listed in one line naming what it is, never an internal error or a silent wrong
answer."""

import json
import shutil

import pytest
import torch
from safetensors.torch import load as st_load

from helpers import interrupted, mikt, rewrite_teacher, runs
from miktcli.registry.runs import open_run

# well-formed but wrong files ----------------------------------------------------------------------------------------

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


# damaged run files --------------------------------------------------------------------------------------------------

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


# damaged or moved run files -----------------------------------------------------------------------------------------

def test_a_binary_run_card_is_damaged_not_an_internal_error(two_vpg_runs, registry):
    (two_vpg_runs / "run1" / "run.json").write_bytes(b"\xff\xfe\x00binary")
    assert "not UTF-8" in mikt("inspect", "run1", code=1).output
    listed = json.loads(mikt("runs", "--json").stdout)
    assert [r.get("error", "") for r in listed if r["run_id"] == "run1"][0].endswith("damaged")


def test_a_renamed_run_folder_and_a_missing_card_say_what_they_are(two_vpg_runs, registry):
    (two_vpg_runs / "run2").rename(two_vpg_runs / "run7")
    assert "names run2 but lives in run7" in mikt("inspect", "run7", code=1).output
    (two_vpg_runs / "run1" / "run.json").unlink()
    r = mikt("inspect", "run1", code=1)
    assert "run.json is missing" in r.output and "known" not in r.output


def test_another_runs_student_file_is_refused(two_vpg_runs, registry):
    shutil.copy(two_vpg_runs / "run2" / "student.safetensors", two_vpg_runs / "run1" / "student.safetensors")
    assert "not run1's student" in mikt("eval", "run1", "--episodes", 1, code=1).output


def test_a_checkpoint_of_another_shape_is_refused_by_eval(two_vpg_runs, registry):
    run = interrupted(open_run(registry, "run1"))
    (run.path / "student.safetensors").unlink()  # eval then reads the checkpoint
    card, tensors = run.load_checkpoint()
    tensors["agent.log_std"] = torch.zeros(7)
    run.save_checkpoint(tensors, card.iteration, card.steps, card.progress)
    r = mikt("eval", "run1", "--episodes", 1, code=1)
    assert "agent tensor 'log_std' has shape (7,)" in r.output


def test_runs_lists_a_run_whose_results_are_null(two_vpg_runs, registry):
    run = open_run(registry, "run1")
    run.save_card(result={**run.card.result, "eval_without_teacher": {"return_mean": None}})
    assert "run1" in mikt("runs").output


def test_a_teacher_with_nan_weights_is_refused(registry, teacher):
    path = registry / "teachers" / "tiny" / "v1.safetensors"
    from safetensors.torch import load as st_load

    tensors = st_load(path.read_bytes())
    tensors["pi.head.bias"] = torch.full_like(tensors["pi.head.bias"], float("nan"))
    rewrite_teacher(path, tensors=tensors)
    assert "NaN or infinite" in mikt("eval", "tiny", "--episodes", 1, code=1).output
