"""A robot added with `mikt envs add` travels with the runs and teachers trained on it (registry/carried.py):
`eval`, `--resume`, `--branch`, `teacher add` and `--from` work from a folder with no spec folder; a tampered
copy is refused in one line; an edited spec in a spec folder is still refused, copy or not."""

import json
import re
from pathlib import Path

import gymnasium as gym
import pytest
from safetensors import safe_open
from safetensors.torch import load as st_load
from safetensors.torch import save as st_save

from helpers import mikt, rewrite_teacher, robot_with_mesh_and_include
from miktcli import limits
from miktcli.registry import carried
from miktcli.registry.cards import TeacherCard
from miktcli.registry.files import CARD_KEY

ASSETS = Path(gym.__file__).parent / "envs" / "mujoco" / "assets"
EVAL = ("--episodes", 1, "--json")


@pytest.fixture()
def my_hopper(specs):
    mikt("envs", "add", ASSETS / "hopper.xml", "--name", "my-hopper")
    return specs


@pytest.fixture()
def elsewhere(tmp_path, monkeypatch):
    """Move to another folder, with no ./envspecs and no $MIKT_ENVSPECS: only the shipped specs are found."""
    def go():
        folder = tmp_path / "elsewhere"
        folder.mkdir()
        monkeypatch.delenv("MIKT_ENVSPECS")
        monkeypatch.chdir(folder)
        assert "unknown environment 'my-hopper'" in mikt("envs", "show", "my-hopper", code=1).output
    return go


def evaluated(target):
    return json.loads(mikt("eval", target, *EVAL).stdout)


@pytest.mark.slow
def test_runs_and_teachers_on_an_added_robot_are_evaluated_and_teach_from_another_folder(
        my_hopper, registry, elsewhere):
    mikt("teacher", "train", "my-hopper", "--steps", 2048, "--name", "t")  # run1, t@v1
    mikt("transfer", "--from", "t", "--to", "my-hopper", "--steps", 2048, "--eval-episodes", 1)  # run2
    mikt("teacher", "add", "run2", "--name", "s")
    assert sorted(p.relative_to(registry / "runs" / "run2" / "env").as_posix()
                  for p in (registry / "runs" / "run2" / "env").rglob("*") if p.is_file()) == \
        ["my-hopper.toml", "my-hopper/hopper.xml"]
    shown = json.loads(mikt("teacher", "show", "s", "--json").stdout)
    assert shown["env_files"] == ["my-hopper.toml", "my-hopper/hopper.xml"] and len(shown["env_fingerprint"]) == 64
    here = {target: evaluated(target) for target in ("run1", "run2", "t", "s")}
    assert all("environment:" not in r["policy"] for r in here.values())  # found in the spec folder

    elsewhere()
    for target in ("run1", "run2", "t", "s"):
        there = evaluated(target)
        who = {"t": "t@v1", "s": "s@v1"}.get(target, target)
        assert there["policy"].endswith(f"(environment: the copy {who} carries)")
        assert (there["env"], there["return_mean"], there["length_mean"]) == \
            (here[target]["env"], here[target]["return_mean"], here[target]["length_mean"])  # the same body
    assert "the copy run2 carries" in mikt("eval", "run2", "--episodes", 1, "--with-teacher").output
    # a new run on the robot: its target from the copy its teacher carries, then carried by the run itself
    out = mikt("transfer", "--from", "s", "--to", "my-hopper", "--steps", 2048, "--eval-episodes", 1).output
    assert "run3: environment 'my-hopper' is in no spec folder: using the copy run3 carries" in out
    card = json.loads((registry / "runs" / "run3" / "run.json").read_text())
    assert card["env_fingerprint"] == shown["env_fingerprint"]
    assert (registry / "runs" / "run3" / "env" / "my-hopper" / "hopper.xml").is_file()
    mikt("transfer", "--from", "t", "--to", "hopper", "--method", "mlpp", "--steps", 2048, "--eval-episodes", 1)
    assert "does not carry" not in mikt("teacher", "add", "run2", "--name", "s2").output
    assert json.loads(mikt("teacher", "show", "s2", "--json").stdout)["env_files"] == shown["env_files"]


def test_without_a_copy_the_error_says_where_it_looked(my_hopper, registry, elsewhere):
    mikt("transfer", "--to", "my-hopper", "--method", "vpg", "--steps", 2048, "--eval-episodes", 1)
    (registry / "runs" / "run1" / "env" / "my-hopper.toml").unlink()
    elsewhere()
    out = mikt("eval", "run1", code=1).output
    assert "cannot evaluate run1: environment 'my-hopper' is in no spec folder" in out
    assert "run1 carries no copy of it" in out and "MIKT_ENVSPECS" in out
    out = mikt("transfer", "--to", "my-hopper", "--method", "vpg", "--steps", 2048, code=1).output
    assert "unknown environment 'my-hopper'" in out


@pytest.mark.slow
def test_an_interrupted_run_resumes_and_branches_from_another_folder(my_hopper, registry, elsewhere,
                                                                     ctrl_c_at_second_update):
    mikt("teacher", "train", "hopper", "--steps", 2048, "--name", "h")
    mikt("transfer", "--from", "h", "--to", "my-hopper", "--steps", 4096, "--drop-teacher-at", 0.5,
         "--eval-episodes", 1, code=1)  # interrupted in its second update, after the kept checkpoint
    elsewhere()
    ctrl_c_at_second_update()
    out = mikt("transfer", "--resume", "run2").output
    assert "run2: environment 'my-hopper' is in no spec folder: using the copy run2 carries" in out
    out = mikt("transfer", "--branch", "run2", "--at", "before-teacher-free", "--handover", "fold").output
    assert "run3: environment 'my-hopper' is in no spec folder: using the copy run3 carries" in out
    assert (registry / "runs" / "run3" / "env" / "my-hopper.toml").is_file()


def test_a_tampered_copy_in_a_run_folder_is_refused(my_hopper, registry, elsewhere):
    mikt("transfer", "--to", "my-hopper", "--method", "vpg", "--steps", 2048, "--eval-episodes", 1)
    elsewhere()
    xml = registry / "runs" / "run1" / "env" / "my-hopper" / "hopper.xml"
    original = xml.read_text()
    xml.write_text(original.replace('name="torso"', 'name="torso" ', 1))  # one byte more
    out = mikt("eval", "run1", code=1).output
    assert "cannot evaluate run1: the copy of environment 'my-hopper' that run1 carries" in out
    assert "does not match run1's card" in out and "tampered or damaged" in out
    xml.unlink()
    assert "is damaged:" in mikt("eval", "run1", code=1).output
    xml.write_text(original)
    evaluated("run1")


def test_an_edited_spec_in_a_spec_folder_is_refused_though_the_run_carries_a_copy(my_hopper, registry):
    mikt("transfer", "--to", "my-hopper", "--method", "vpg", "--steps", 2048, "--eval-episodes", 1)
    path = my_hopper / "my-hopper.toml"
    path.write_text(re.sub(r"^ctrl_cost_weight = .*$", "ctrl_cost_weight = 500", path.read_text(), flags=re.M))
    out = mikt("eval", "run1", code=1).output
    assert "cannot evaluate run1: environment 'my-hopper' changed since it started" in out
    assert "run1 carries its own copy" in out


def _rewrite_carried(path, change):
    """Rewrite a teacher file with `change(card_dict, tensors)` applied (the policy's sha256 untouched)."""
    with safe_open(str(path), "pt") as f:
        card = json.loads(f.metadata()[CARD_KEY])
    tensors = st_load(path.read_bytes())
    change(card, tensors)
    path.write_bytes(st_save(tensors, metadata={CARD_KEY: json.dumps(card)}))


def test_a_teacher_carries_its_meshes_and_includes_and_a_tampered_one_is_refused(specs, registry, tmp_path,
                                                                                 elsewhere):
    mikt("envs", "add", robot_with_mesh_and_include(tmp_path / "robot"), "--name", "bot")
    mikt("teacher", "train", "bot", "--steps", 2048, "--name", "b")
    teacher = registry / "teachers" / "b" / "v1.safetensors"
    files = json.loads(mikt("teacher", "show", "b", "--json").stdout)["env_files"]
    assert files == ["bot.toml", "bot/bot.xml", "bot/motors.xml", "bot/meshes/foot.obj"]
    elsewhere()
    before = teacher.read_bytes()
    assert evaluated("b")["policy"] == "b@v1 (environment: the copy b@v1 carries)"

    def flip_mesh(card, tensors):
        tensors["env/bot/meshes/foot.obj"][0] ^= 1
    _rewrite_carried(teacher, flip_mesh)  # a flipped byte: the file's sha256 says so whenever it is read
    assert "tensors do not match the card's sha256 (tampered or corrupted)" in mikt("eval", "b", code=1).output
    teacher.write_bytes(before)
    tensors = st_load(teacher.read_bytes())
    tensors["env/bot/meshes/foot.obj"][0] ^= 1
    rewrite_teacher(teacher, tensors=tensors)  # and with the card's sha256 rewritten to match: the fingerprint
    out = mikt("eval", "b", code=1).output
    assert "cannot evaluate b@v1: the copy of environment 'bot' that b@v1 carries (in its file) does not match" in out

    def escape(card, tensors):
        tensors["env/../../x"] = tensors.pop("env/bot/motors.xml")
        card["env_files"] = [p if p != "bot/motors.xml" else "../../x" for p in card["env_files"]]
    teacher.write_bytes(before)
    _rewrite_carried(teacher, escape)
    assert "carried file name '../../x' is not a plain relative path (tampered)" in mikt("eval", "b", code=1).output

    def unlisted(card, tensors):
        card["env_files"] = card["env_files"][:2]
    teacher.write_bytes(before)
    _rewrite_carried(teacher, unlisted)
    assert "but its card lists bot.toml, bot/bot.xml (tampered)" in mikt("teacher", "show", "b", code=1).output
    teacher.write_bytes(before)
    evaluated("b")


def test_a_packaged_teacher_carries_its_robot_and_nothing_is_written_beside_it(my_hopper, registry, tmp_path,
                                                                             monkeypatch, elsewhere):
    from miktcli.registry import packaged

    mikt("teacher", "train", "my-hopper", "--steps", 2048, "--name", "pk")
    root = tmp_path / "package" / "_teachers"
    (root / "pk").mkdir(parents=True)
    (registry / "teachers" / "pk" / "v1.safetensors").rename(root / "pk" / "v1.safetensors")
    root.chmod(0o555)
    (root / "pk").chmod(0o555)
    monkeypatch.setattr(packaged, "packaged_root", lambda: root)
    monkeypatch.setenv("MIKT_PACKAGED_TEACHERS", "1")
    try:
        elsewhere()
        assert evaluated("pk")["policy"] == "pk@v1 (environment: the copy pk@v1 carries)"
        assert sorted(p.name for p in root.rglob("*")) == ["pk", "v1.safetensors"]
    finally:
        (root / "pk").chmod(0o755)
        root.chmod(0o755)


def test_a_model_that_cannot_travel_is_said_so_and_trains_as_before(my_hopper, registry, monkeypatch, elsewhere):
    path = my_hopper / "my-hopper.toml"  # the spec names its XML by an absolute path: it stays where it lies
    xml = (my_hopper / "my-hopper" / "hopper.xml").resolve()
    path.write_text(re.sub(r'^xml = .*$', f'xml = "{xml}"', path.read_text(), flags=re.M))
    out = mikt("transfer", "--to", "my-hopper", "--method", "vpg", "--steps", 2048, "--eval-episodes", 1).output
    assert "note: run1 does not carry environment 'my-hopper' (its spec names its XML by an absolute path" in out
    assert not (registry / "runs" / "run1" / "env").exists()
    monkeypatch.setattr(limits, "MAX_CARRIED_MODEL_BYTES", 100)  # and a model larger than a copy may be
    out = mikt("teacher", "train", "hopper", "--steps", 2048, "--name", "big").output
    assert "pass the 100 bytes a run or teacher carries" in out
    assert "publish big (without its environment: its spec and model files pass the 100 bytes" in out
    assert "note: big@v1 does not carry environment 'hopper'" in out
    assert json.loads(mikt("teacher", "show", "big", "--json").stdout)["env_files"] == []
    evaluated("big")  # a shipped spec: found anyway
    elsewhere()
    assert "run1 carries no copy of it" in mikt("eval", "run1", code=1).output


def test_a_run_whose_copy_cannot_be_written_is_not_left_behind(registry, monkeypatch):
    def full(files, folder):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(carried, "_write_files", full)
    out = mikt("transfer", "--to", "hopper", "--method", "vpg", "--steps", 2048, code=1).output
    assert "cannot write" in out and "No space left on device" in out and "free some space" in out
    assert not (registry / "runs").exists() or list((registry / "runs").iterdir()) == []


def test_every_run_carries_its_spec_and_a_student_records_the_fingerprint(registry):
    mikt("transfer", "--to", "hopper", "--method", "vpg", "--steps", 2048, "--eval-episodes", 1)
    run = registry / "runs" / "run1"
    assert sorted(p.name for p in (run / "env").iterdir()) == ["hopper.toml"]
    with safe_open(str(run / "student.safetensors"), "pt") as f:
        student = TeacherCard.model_validate_json(f.metadata()[CARD_KEY])
    assert student.env_fingerprint == json.loads((run / "run.json").read_text())["env_fingerprint"]
    assert student.env_files == []  # the run folder carries it; `teacher add` puts it into the teacher
