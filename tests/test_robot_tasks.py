"""`mikt envs add` makes a task that makes sense on robots no one here wrote: it resets from the `home`
keyframe, maps actions onto each actuator's ctrlrange, adds a floor where there is none, removes free bodies
that are not the robot, pays nothing for standing still, and says what it chose and what may spoil the task."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from helpers import mikt
from miktcli.envs import load_spec, make_env
from miktcli.envs.fingerprint import spec_fingerprint, spec_record
from miktcli.envs.probe import probe
from miktcli.envs.spec import MjcfSpec

QUADRUPED = Path(__file__).parent / "fixtures" / "robots" / "quadruped"
ASSETS = Path(gym.__file__).parent / "envs" / "mujoco" / "assets"

# A planar runner in the manner of dm_control's cheetah: stiff sprung joints, motors with ctrlrange [-1, 1], a
# torso that rests well above half its height on its legs, so it cannot fall below the default health check.
RUNNER = """<mujoco model="runner">
  <option timestep="0.01"/>
  <default><joint limited="true" damping="3" stiffness="100" armature=".1" type="hinge" axis="0 1 0"/>
    <motor ctrllimited="true" ctrlrange="-1 1"/></default>
  <worldbody>
    <geom name="ground" type="plane" size="50 1 .5"/>
    <body name="torso" pos="0 0 .7">
      <joint name="rootx" type="slide" axis="1 0 0" limited="false" stiffness="0" damping="0"/>
      <joint name="rootz" type="slide" axis="0 0 1" limited="false" stiffness="0" damping="0"/>
      <joint name="rooty" type="hinge" axis="0 1 0" limited="false" stiffness="0" damping="0"/>
      <geom type="capsule" fromto="-.5 0 0 .5 0 0" size=".046"/>
      <body name="back" pos="-.5 0 0"><joint name="back" range="-10 10"/>
        <geom type="capsule" fromto="0 0 0 0 0 -.65" size=".046"/></body>
      <body name="front" pos=".5 0 0"><joint name="front" range="-10 10"/>
        <geom type="capsule" fromto="0 0 0 0 0 -.65" size=".046"/></body>
    </body>
  </worldbody>
  <actuator><motor name="back" joint="back" gear="60"/><motor name="front" joint="front" gear="60"/></actuator>
</mujoco>
"""


def _spec_file(specs: Path, name: str) -> dict:
    import tomllib

    return tomllib.loads((specs / f"{name}.toml").read_text())


def test_a_menagerie_style_quadruped_resets_to_home_and_a_zero_action_holds_it(specs):
    r = mikt("envs", "add", QUADRUPED / "scene.xml", "--name", "quad")
    assert "resets to the model's 'home' keyframe (spec key: keyframe)" in r.output
    assert "no healthy bonus, so standing still earns nothing (spec key: healthy_reward)" in r.output
    written = _spec_file(specs, "quad")
    assert written["keyframe"] == "home" and written["action_map"] == "ctrlrange"
    assert written["healthy_reward"] == 0.0 and written["floor"] is False

    env = make_env("quad")
    base = env.unwrapped
    home = base.model.key("home")
    noise = load_spec("quad").reset_noise_scale
    for seed in range(3):
        env.reset(seed=seed)
        assert np.all(np.abs(base.data.qpos - home.qpos) <= noise)  # the home pose, within the reset noise
    # actions span the ctrlrange around the home pose: 0 holds it, ±1 reach the ends
    assert np.allclose(base.ctrl_map(np.zeros(12)), home.ctrl)
    assert np.allclose(base.ctrl_map(np.ones(12)), base.model.actuator_ctrlrange[:, 1])
    assert np.allclose(base.ctrl_map(-np.ones(12)), base.model.actuator_ctrlrange[:, 0])
    assert env.action_space.low.min() == -1.0 and env.action_space.high.max() == 1.0
    standing = probe(base, "zero")
    assert standing.lengths == [1000] and not standing.fell[0]
    assert abs(standing.returns[0]) < 0.1 * 1000  # standing still pays < 10 % of max_episode_steps
    assert base.root_position()[2] > 0.2  # still standing on bent legs (home trunk height 0.28)
    env.close()


def test_a_quadruped_without_a_floor_gets_one_and_stands_on_it(specs):
    r = mikt("envs", "add", QUADRUPED / "quadruped.xml", "--name", "quad-bare")
    assert "warning: the model has no floor (the robot would fall into the void): adds a ground plane at z = 0 " \
           "(spec key: floor)" in r.output
    assert _spec_file(specs, "quad-bare")["floor"] is True
    env = make_env("quad-bare")
    result = probe(env.unwrapped, "zero")
    assert result.lengths == [1000] and env.unwrapped.root_position()[2] > 0.2
    env.close()
    # floor = false is the model as it is: the robot falls through, and the health check ends the episode
    text = (specs / "quad-bare.toml").read_text().replace("floor = true", "floor = false")
    (specs / "quad-bare.toml").write_text(text)
    env = make_env("quad-bare")
    assert probe(env.unwrapped, "zero").fell == [True]
    env.close()


def test_a_body_that_cannot_fall_is_warned_about_and_standing_still_pays_nothing(specs, tmp_path):
    (tmp_path / "runner.xml").write_text(RUNNER)
    r = mikt("envs", "add", tmp_path / "runner.xml", "--name", "runner")
    assert "no probe episode ended by the health check (root height > 0.35): the body may be unable to fall" \
           in r.output and "(spec key: healthy_z_min)" in r.output
    assert "probe, a zero action: return " in r.output and "probe, random actions: return " in r.output
    assert _spec_file(specs, "runner")["healthy_reward"] == 0.0
    env = make_env("runner")
    standing = probe(env.unwrapped, "zero")
    assert standing.lengths == [1000] and abs(standing.returns[0]) < 100
    env.close()


def test_a_body_that_falls_keeps_gymnasiums_healthy_bonus(specs):
    r = mikt("envs", "add", ASSETS / "hopper.xml", "--name", "my-hopper")
    assert "healthy_reward" not in r.output and "unable to fall" not in r.output
    assert _spec_file(specs, "my-hopper")["healthy_reward"] == 1.0


def test_free_bodies_and_height_fields_beside_the_floor_are_removed_and_said(specs, tmp_path):
    ball = RUNNER.replace("</worldbody>", '<body name="ball" pos="2 0 1"><freejoint/><geom size=".1"/></body>'
                          '<geom name="bumps" type="hfield" hfield="bumps"/></worldbody>')
    ball = ball.replace("<worldbody>", '<asset><hfield name="bumps" nrow="20" ncol="20" size="5 5 .1 .1"/>'
                        "</asset><worldbody>")
    (tmp_path / "ball.xml").write_text(ball)
    r = mikt("envs", "add", tmp_path / "ball.xml", "--name", "with-ball")
    assert "free bodies that are not the robot (ball) would be in the observation: removes them" in r.output
    assert "height field(s) bumps beside the floor" in r.output
    assert _spec_file(specs, "with-ball")["remove"] == ["ball", "bumps"]
    (tmp_path / "plain.xml").write_text(RUNNER)
    mikt("envs", "add", tmp_path / "plain.xml", "--name", "plain")
    assert load_spec("with-ball").obs_dim == load_spec("plain").obs_dim  # the ball is not observed


def test_an_actuator_with_no_ctrlrange_is_warned_about(specs, tmp_path):
    motor = '<motor name="back" joint="back" gear="60"/>'
    (tmp_path / "free.xml").write_text(RUNNER.replace(motor, motor.replace("/>", ' ctrllimited="false"/>')))
    r = mikt("envs", "add", tmp_path / "free.xml", "--name", "loose")
    assert "1 actuator(s) have no ctrlrange (back): the policy's actions reach them unscaled" in r.output
    env = make_env("loose")
    assert env.unwrapped.ctrl_map(np.array([5.0, 5.0]))[0] == 5.0  # unscaled
    assert env.unwrapped.ctrl_map(np.array([5.0, 5.0]))[1] == 1.0  # clipped to [-1, 1], then its ctrlrange
    env.close()


@pytest.mark.parametrize("edit, message", [
    ('keyframe = "crouch"', "keyframe: the model has no keyframe named 'crouch' (keyframes: home)"),
    ('remove = ["tail"]', "remove: no body or geom named 'tail' (bodies: trunk, FR_hip,"),
    ('remove = ["trunk", "trunk"]', "names a body or geom twice"),
    ('action_map = "scaled"', "action_map"),
])
def test_bad_task_fields_are_one_line(specs, edit, message):
    mikt("envs", "add", QUADRUPED / "scene.xml", "--name", "quad")
    path = specs / "quad.toml"
    key = edit.split(" = ")[0]
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith(f"{key} =")]
    path.write_text("\n".join(lines) + f"\n{edit}\n")
    assert message in mikt("envs", "show", "quad", code=1).output


def test_a_spec_written_before_the_task_fields_keeps_its_fingerprint(tmp_path):
    """Runs recorded specs (and their fingerprints) before keyframe, action_map, floor and remove existed: at
    their defaults those fields are left out of the record, so the same file is still the same task."""
    fields = dict(name="h", family="mjcf", xml=str(ASSETS / "hopper.xml"), obs_dim=11, act_dim=3)
    old = MjcfSpec(**fields)
    explicit = MjcfSpec(**fields, keyframe=None, action_map="raw", floor=False, remove=[])
    assert spec_record(old) == spec_record(explicit)
    assert not {"keyframe", "action_map", "floor", "remove"} & spec_record(old).keys()
    assert spec_fingerprint(old) == spec_fingerprint(explicit)
    assert spec_fingerprint(MjcfSpec(**fields, action_map="ctrlrange")) != spec_fingerprint(old)


def test_envs_show_lists_the_task_fields(specs):
    mikt("envs", "add", QUADRUPED / "scene.xml", "--name", "quad")
    shown = json.loads(mikt("envs", "show", "quad", "--json").stdout)["spec"]
    assert (shown["keyframe"], shown["action_map"], shown["remove"]) == ("home", "ctrlrange", [])
