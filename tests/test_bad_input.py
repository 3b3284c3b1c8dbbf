"""Clumsy and hostile input found by a review of the CLI: each case named, reproduced and handled with a
one-line error (exit 1) or a usage error (exit 2), never an internal error or a silent wrong answer."""

import json
import shutil

import pytest
import torch

from helpers import mikt, rewrite_teacher
from miktcli.registry.runs import open_run

TINY = ("--steps", 2048)


@pytest.fixture()
def two_vpg_runs(registry):
    """Two finished vpg runs on hopper (run1, run2): checkpoints and students on disk."""
    for seed in (0, 1):
        mikt("transfer", "--to", "hopper", "--method", "vpg", *TINY, "--seed", seed, "--eval-episodes", 1)
    return registry / "runs"


def interrupted(run):
    run.save_card(status="interrupted")
    return run


# resume -------------------------------------------------------------------------------------------------------

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


# damaged or moved run files -------------------------------------------------------------------------------------

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


def test_a_teacher_with_nan_weights_is_refused(registry):
    mikt("teacher", "train", "hopper", *TINY, "--name", "tiny")
    path = registry / "teachers" / "tiny" / "v1.safetensors"
    from safetensors.torch import load as st_load

    tensors = st_load(path.read_bytes())
    tensors["pi.head.bias"] = torch.full_like(tensors["pi.head.bias"], float("nan"))
    rewrite_teacher(path, tensors=tensors)
    assert "NaN or infinite" in mikt("eval", "tiny", "--episodes", 1, code=1).output


# options --------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("args", [("eval", "hopper", "--seed", -5), ("eval", "hopper", "--seed", 2**33),
                                  ("eval", "hopper", "--seed", 2**32 - 1, "--episodes", 2),
                                  ("envs", "render", "hopper", "--seed", -1)])
def test_seeds_outside_0_to_2_32_are_usage_errors(registry, args):
    mikt(*args, code=2)


def test_an_infinite_coefficient_is_refused(registry):
    mikt("teacher", "train", "hopper", *TINY, "--name", "tiny")
    r = mikt("transfer", "--from", "tiny", "--to", "hopper", "--mi-coef", "inf", *TINY, code=1)
    assert "mi_coef" in r.output and "finite" in r.output
    r = mikt("transfer", "--to", "hopper", "--method", "vpg", "--kl-coef", "inf", *TINY, code=1)
    assert "kl_coef" in r.output
    assert [p.name for p in (registry / "runs").iterdir()] == ["run1"]  # the teacher's run only


def test_hidden_sizes_with_an_empty_piece_are_refused(registry):
    assert "expected comma-separated integers" in mikt("teacher", "train", "hopper", "--hidden", "64,,64",
                                                       code=1).output


def test_plot_needs_a_view_and_a_file_not_a_folder(two_vpg_runs, registry, tmp_path):
    assert "--coupling or --curve" in mikt("inspect", "run1", "--plot", tmp_path / "x.png", code=2).output
    r = mikt("inspect", "run1", "--curve", "--plot", tmp_path, code=1)
    assert "is a folder" in r.output
    (tmp_path / "dir.mp4").mkdir()
    assert "is a folder" in mikt("eval", "run1", "--episodes", 1, "--video", tmp_path / "dir.mp4", code=1).output
    # an .png video would be overwritten by its own poster
    assert "not an .mp4 path" in mikt("eval", "run1", "--episodes", 1, "--video", tmp_path / "v.png", code=2).output


def test_an_unwritable_video_path_is_refused_before_the_episodes(two_vpg_runs, registry, tmp_path, monkeypatch):
    import os

    if os.geteuid() == 0:
        pytest.skip("root writes anywhere")
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        r = mikt("eval", "run1", "--episodes", 1, "--video", locked / "v.mp4", code=1)
        assert "not writable" in r.output
    finally:
        locked.chmod(0o700)


def test_a_mikt_run_without_metrics_has_no_weights_yet(registry):
    from miktcli.workflows.transfer import start_transfer

    mikt("teacher", "train", "hopper", *TINY, "--name", "tiny")
    run = start_transfer(registry, to="hopper", method="mikt", teacher_refs=["tiny"], steps=2048, seed=0,
                         command="test")
    assert "no mixing weights yet" in mikt("inspect", run.id, "--coupling", code=1).output


# where things live ------------------------------------------------------------------------------------------------

def test_a_registry_that_is_a_file_is_an_error_not_an_empty_listing(tmp_path, monkeypatch):
    afile = tmp_path / "afile"
    afile.write_text("x")
    monkeypatch.setenv("MIKT_REGISTRY", str(afile))
    assert "is a file, not a folder" in mikt("runs", code=1).output
    assert "is a file, not a folder" in mikt("teacher", "list", code=1).output


@pytest.mark.parametrize("where", ["missing", "file"])
def test_an_envspecs_override_that_is_not_a_folder_is_an_error(tmp_path, monkeypatch, where):
    path = tmp_path / "specs"
    if where == "file":
        path.write_text("x")
    monkeypatch.setenv("MIKT_ENVSPECS", str(path))
    assert "is not a folder" in mikt("envs", "--json", code=1).output


# found by the second review ---------------------------------------------------------------------------------------

def test_options_of_another_method_are_refused_not_ignored(registry, tmp_path):
    mikt("teacher", "train", "hopper", *TINY, "--name", "tiny")
    r = mikt("transfer", "--method", "mlpp", "--from", "tiny", "--to", "hopper", "--no-mi", *TINY, code=2)
    assert "'--mi'" in r.output and "does not apply to --method mlpp" in r.output
    r = mikt("transfer", "--from", "tiny", "--from", "tiny@v1", "--to", "hopper", *TINY, code=1)
    assert "teacher tiny@v1 is given more than once" in r.output
    grid = tmp_path / "g.toml"
    grid.write_text('name = "x"\nsteps = 2048\nseeds = [0]\n[[pairs]]\nfrom = ["tiny"]\nto = "hopper"\n'
                    '[[methods]]\nname = "vpg"\nmethod = "vpg"\nmikt = { mi = false }\n')
    assert "method vpg takes no options; got mi" in mikt("study", grid, "--out", tmp_path / "out", code=1).output
    assert [p.name for p in (registry / "runs").iterdir()] == ["run1"]  # the teacher's run only


def test_an_empty_or_reversed_coupling_ramp_is_refused(registry):
    from miktcli.errors import MiktError
    from miktcli.workflows.transfer import start_transfer

    mikt("teacher", "train", "hopper", *TINY, "--name", "tiny")
    for ramp in ({"ramp_start": 0.5, "drop_teacher_at": 0.5}, {"ramp_start": 0.9, "drop_teacher_at": 0.2},
                 {"drop_teacher_at": 1.5}):
        with pytest.raises(MiktError, match="bad mikt option"):
            start_transfer(registry, to="hopper", method="mikt", teacher_refs=["tiny"], steps=2048, seed=0,
                           command="test", options=ramp)


def test_a_name_with_a_trailing_newline_is_refused(registry):
    assert "invalid teacher name" in mikt("teacher", "train", "hopper", *TINY, "--name", "nl\n", code=1).output


def test_teacher_list_names_files_stored_under_another_name(registry):
    mikt("teacher", "train", "hopper", *TINY, "--name", "tiny")
    copy = registry / "teachers" / "copy" / "v7.safetensors"
    copy.parent.mkdir()
    shutil.copy(registry / "teachers" / "tiny" / "v1.safetensors", copy)
    r = mikt("teacher", "list", code=1)
    assert "copy@v7" in r.output and "1 teacher file(s)" in r.output
    from helpers import runner
    from miktcli.cli.app import app

    result = runner.invoke(app, ["teacher", "list", "--json"])  # stdout: the JSON; stderr: the error line
    assert result.exit_code == 1
    listed = json.loads(result.stdout)
    assert [(row["ref"], row["error"] is None) for row in listed] == [("copy@v7", False), ("tiny@v1", True)]
