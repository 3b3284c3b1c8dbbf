"""`mikt envs add`: your own robot from an MJCF file, to a transfer and a video; bad files write nothing."""

from __future__ import annotations

import json
import os
from pathlib import Path

import gymnasium as gym
import pytest

from helpers import mikt, robot_with_mesh_and_include

ASSETS = Path(gym.__file__).parent / "envs" / "mujoco" / "assets"




def test_walker2d_from_gymnasium_xml_is_added_and_trained_from_the_packaged_hopper(specs, registry, monkeypatch,
                                                                                    tmp_path):
    r = mikt("envs", "add", ASSETS / "walker2d_v5.xml", "--name", "walker")
    assert r.stdout.strip() == str(specs / "walker.toml")
    assert "actuators (6): thigh_joint, leg_joint, foot_joint" in r.output
    assert "torso: torso (slide root: rootx, rootz, rooty)" in r.output
    assert (specs / "walker" / "walker2d_v5.xml").read_bytes() == (ASSETS / "walker2d_v5.xml").read_bytes()
    shown = json.loads(mikt("envs", "show", "walker", "--json").stdout)
    assert (shown["spec"]["obs_dim"], shown["spec"]["act_dim"]) == (17, 6)
    assert shown["spec"]["xml"] == "walker/walker2d_v5.xml" and len(shown["model"]["actuators"]) == 6
    names = [d["name"] for d in json.loads(mikt("envs", "--json").stdout)]
    assert "walker" in names and "hopper" in names  # your specs sit above the shipped ones

    # the spec keeps working from anywhere: the XML was copied beside it
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MIKT_PACKAGED_TEACHERS", "1")
    r = mikt("transfer", "--from", "hopper", "--to", "walker", "--steps", 2048, "--eval-episodes", 1, "--json")
    assert json.loads(r.stdout)["run"] == "run1"
    card = json.loads(mikt("inspect", "--json").stdout)["card"]  # no target: the newest run
    assert card["run_id"] == "run1" and card["env"] == "walker" and card["steps_done"] == 2048
    assert card["teachers"][0]["name"] == "hopper"  # the packaged teacher: this registry has none
    assert not (registry / "teachers").exists()

    # eval with no target: the newest run, its video named after it
    r = mikt("eval", "--render-offscreen", "--episodes", 1, "--video-frames", 5)
    assert (tmp_path / "run1-eval.mp4").stat().st_size > 0 and (tmp_path / "run1-eval.png").exists()
    assert "run1 student on walker" in r.stdout


def test_an_xml_with_meshes_and_includes_is_copied_with_them(specs, tmp_path):
    robot = tmp_path / "vendor"
    robot_with_mesh_and_include(robot)
    r = mikt("envs", "add", robot / "bot.xml", "--name", "bot")
    assert "copied the XML and 2 file(s)" in r.output
    assert (specs / "bot" / "meshes" / "foot.obj").is_file() and (specs / "bot" / "motors.xml").is_file()
    import shutil

    shutil.rmtree(robot)  # the user moves on
    shown = json.loads(mikt("envs", "show", "bot", "--json").stdout)
    assert shown["spec"]["torso"] == "base" and shown["model"]["actuators"] == ["hip"]
    assert shown["spec"]["obs_dim"] == (8 - 2) + 7  # free joint's qpos without x, y; then qvel


BAD = {
    "unparsable": ("<mujoco><worldbody><body>", "not a valid MJCF model"),
    "no_actuator": ('<mujoco><worldbody><body><freejoint/><geom size="0.1"/></body></worldbody></mujoco>',
                    "the model has no actuator"),
    "no_root": ('<mujoco><worldbody><body><joint name="j"/><geom size="0.1"/></body></worldbody>'
                '<actuator><motor joint="j"/></actuator></mujoco>', "no free or slide root joint"),
}


@pytest.mark.parametrize("case", [*BAD, "missing", "unreadable", "directory"])
def test_bad_files_are_one_error_line_and_write_nothing(specs, tmp_path, case):
    path = tmp_path / f"{case}.xml"
    if case in BAD:
        path.write_text(BAD[case][0])
    elif case == "unreadable":
        path.write_text(BAD["no_actuator"][0])
        path.chmod(0)
        if os.access(path, os.R_OK):  # root reads anything: that case cannot be made here
            pytest.skip("running as root: every file is readable")
    elif case == "directory":
        path.mkdir()
    r = mikt("envs", "add", path, "--name", "robot", code=1)
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"Error: {path}: "), r.output
    want = {"missing": "no such file", "unreadable": "cannot be read", "directory": "not a file"}
    assert (BAD[case][1] if case in BAD else want[case]) in lines[0]
    assert list(specs.iterdir()) == []


def test_names_are_checked_before_anything_is_written(specs):
    assert "exists already" in mikt("envs", "add", ASSETS / "hopper.xml", "--name", "hopper", code=1).output
    assert "invalid environment name" in mikt("envs", "add", ASSETS / "hopper.xml", "--name", "A/b", code=1).output
    assert list(specs.iterdir()) == []


def test_a_name_ending_in_toml_is_refused_before_anything_is_written(specs):
    out = mikt("envs", "add", ASSETS / "hopper.xml", "--name", "w.toml", code=1).output
    assert "it may not end in .toml" in out and "--name w" in out
    assert not list(specs.iterdir())
    mikt("envs")  # still lists


@pytest.mark.parametrize("in_place", [False, True])
def test_two_adds_of_one_name_at_once_leave_the_first_and_refuse_the_second(specs, tmp_path, monkeypatch, in_place):
    from miktcli.workflows import add_env

    xml = ASSETS / "hopper.xml"
    if in_place:  # a model that loads a file outside its folder is not copied: only the spec file is written
        monkeypatch.setattr(add_env, "_relative", lambda path, folder: None)
    real = add_env.load_model

    def the_other_add_finishes_first(path):
        model = real(path)
        (specs / "bot.toml").write_text("# the other add's spec\n")
        if not in_place:
            (specs / "bot").mkdir()
        return model

    monkeypatch.setattr(add_env, "load_model", the_other_add_finishes_first)
    out = mikt("envs", "add", xml, "--name", "bot", code=1).output
    assert "exists already" in out
    assert (specs / "bot.toml").read_text() == "# the other add's spec\n"


def test_the_copy_is_exact_sub_models_symlinks_and_absolute_paths(specs, tmp_path):
    robot = tmp_path / "vendor"
    robot.mkdir()
    (robot / "leg.xml").write_text(
        '<mujoco><worldbody><body name="thigh"><joint name="hip" type="hinge" axis="0 1 0"/>'
        '<geom type="capsule" size="0.05" fromto="0 0 0 0 0 -0.3"/></body></worldbody>'
        '<actuator><motor joint="hip" gear="10"/></actuator></mujoco>')
    body = ('<geom type="plane" size="5 5 .1"/><body name="base" pos="0 0 0.5"><freejoint/>'
            '<geom type="sphere" size="0.1"/><attach model="leg" body="thigh" prefix="l_"/></body>')
    (robot / "bot.xml").write_text(f'<mujoco><asset><model name="leg" file="leg.xml"/></asset>'
                                   f'<worldbody>{body}</worldbody></mujoco>')
    r = mikt("envs", "add", robot / "bot.xml", "--name", "bot")  # a sub-model (MuJoCo's attach) goes along
    assert "copied the XML and 1 file(s)" in r.output and (specs / "bot" / "leg.xml").is_file()

    (robot / "parts").mkdir()
    (robot / "leg.xml").rename(robot / "parts" / "real-leg.xml")
    (robot / "leg.xml").symlink_to(robot / "parts" / "real-leg.xml")  # a link inside the folder
    mikt("envs", "add", robot / "bot.xml", "--name", "linked")
    assert (specs / "linked" / "leg.xml").read_text() == (robot / "parts" / "real-leg.xml").read_text()
    mikt("envs", "show", "linked")

    (robot / "abs.xml").write_text(f'<mujoco><asset><model name="leg" file="{robot / "leg.xml"}"/></asset>'
                                   f'<worldbody>{body}</worldbody></mujoco>')
    r = mikt("envs", "add", robot / "abs.xml", "--name", "absolute")
    assert f"in place (it names {robot / 'leg.xml'} by an absolute path)" in r.output
    assert not (specs / "absolute").exists()  # used in place: a copy would still read the original


def test_a_model_mujoco_cannot_simulate_is_refused_at_add_time(specs, tmp_path):
    # a collision pass larger than the model's arena: every later command (render, train, eval) would die in
    # MuJoCo's mj_stackAlloc; 200 overlapping spheres in 64 KB do it quickly (20,000 bodies do it by default)
    spheres = "".join(f'<body pos="{i % 20 * 0.01} {i // 20 * 0.01} 0"><geom type="sphere" size="0.001"/></body>'
                      for i in range(200))
    xml = tmp_path / "crowded.xml"
    xml.write_text('<mujoco><size memory="64K"/><worldbody><geom type="plane" size="5 5 .1"/>'
                   '<body name="torso" pos="0 0 1"><freejoint/><geom type="sphere" size="0.1"/>'
                   '<body name="leg"><joint name="hip" type="hinge"/>'
                   '<geom type="capsule" size="0.02" fromto="0 0 0 0 0 -0.3"/></body>' + spheres +
                   '</body></worldbody><actuator><motor joint="hip"/></actuator></mujoco>')
    out = mikt("envs", "add", xml, "--name", "crowded", code=1).output
    assert "MuJoCo cannot simulate the model: mj_stackAlloc" in out and "<size memory" in out
    assert not list(specs.iterdir())
