"""Clumsy and hostile command-line input: outside text never acts on the terminal, arguments are checked
before any work, references are names not paths, and OS errors, bad specs, names and options are one-line
errors (exit 1) or usage errors (exit 2)."""

import json
import os
import shutil

import pytest

from helpers import TINY, mikt, rewrite_teacher, runner, runs, spec_dir
from miktcli.cli.app import app

# outside text never acts on the terminal ----------------------------------------------------------------------------

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


# validation before any work -----------------------------------------------------------------------------------------

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


# references are never paths -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("ref", ["../x@v1", "/etc/passwd", "a/../../b", "..", "./tiny"])
def test_teacher_refs_are_names_not_paths(teacher, ref):
    assert "invalid teacher name" in mikt("teacher", "show", ref, code=1).output
    mikt("eval", ref, code=1)
    mikt("inspect", ref, code=1)


# OS errors are user errors ------------------------------------------------------------------------------------------

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


# where things live --------------------------------------------------------------------------------------------------

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


# spec files ---------------------------------------------------------------------------------------------------------

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


# names --------------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["", "last", "run3", "latest", "Bad", "a/b", ".hidden"])
def test_reserved_and_bad_names_are_refused(registry, name):
    mikt("teacher", "train", "hopper", "--steps", 2048, "--name", name, code=1)
    assert runs(registry) == []


# options ------------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("args", [("eval", "hopper", "--seed", -5), ("eval", "hopper", "--seed", 2**33),
                                  ("eval", "hopper", "--seed", 2**32 - 1, "--episodes", 2),
                                  ("envs", "render", "hopper", "--seed", -1)])
def test_seeds_outside_0_to_2_32_are_usage_errors(registry, args):
    mikt(*args, code=2)


def test_an_infinite_coefficient_is_refused(registry, teacher):
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


def test_a_mikt_run_without_metrics_has_no_weights_yet(registry, teacher):
    from miktcli.workflows.transfer import start_transfer

    run = start_transfer(registry, to="hopper", method="mikt", teacher_refs=["tiny"], steps=2048, seed=0,
                         command="test")
    assert "no mixing weights yet" in mikt("inspect", run.id, "--coupling", code=1).output


def test_options_of_another_method_are_refused_not_ignored(registry, tmp_path, teacher):
    r = mikt("transfer", "--method", "mlpp", "--from", "tiny", "--to", "hopper", "--no-mi", *TINY, code=2)
    assert "'--mi'" in r.output and "does not apply to --method mlpp" in r.output
    r = mikt("transfer", "--from", "tiny", "--from", "tiny@v1", "--to", "hopper", *TINY, code=1)
    assert "teacher tiny@v1 is given more than once" in r.output
    grid = tmp_path / "g.toml"
    grid.write_text('name = "x"\nsteps = 2048\nseeds = [0]\n[[pairs]]\nfrom = ["tiny"]\nto = "hopper"\n'
                    '[[methods]]\nname = "vpg"\nmethod = "vpg"\nmikt = { mi = false }\n')
    assert "method vpg takes no options; got mi" in mikt("study", grid, "--out", tmp_path / "out", code=1).output
    assert [p.name for p in (registry / "runs").iterdir()] == ["run1"]  # the teacher's run only


def test_an_empty_or_reversed_coupling_ramp_is_refused(registry, teacher):
    from miktcli.errors import MiktError
    from miktcli.workflows.transfer import start_transfer

    for ramp in ({"ramp_start": 0.5, "drop_teacher_at": 0.5}, {"ramp_start": 0.9, "drop_teacher_at": 0.2},
                 {"drop_teacher_at": 1.5}):
        with pytest.raises(MiktError, match="bad mikt option"):
            start_transfer(registry, to="hopper", method="mikt", teacher_refs=["tiny"], steps=2048, seed=0,
                           command="test", options=ramp)


def test_a_name_with_a_trailing_newline_is_refused(registry):
    assert "invalid teacher name" in mikt("teacher", "train", "hopper", *TINY, "--name", "nl\n", code=1).output


def test_teacher_list_names_files_stored_under_another_name(registry, teacher):
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
