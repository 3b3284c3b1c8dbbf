"""The mjcf family: built from gymnasium's own XML files with their documented weights, it is Hopper-v5 and
Walker2d-v5 step for step; and its spec is checked like the others."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from miktcli.envs import make_env
from miktcli.envs.spec import MjcfSpec, load_spec_file
from miktcli.errors import MiktError

ASSETS = Path(gym.__file__).parent / "envs" / "mujoco" / "assets"

# Hopper-v5 and Walker2d-v5 as gymnasium documents them (their constructors' defaults)
HOPPER = dict(xml=str(ASSETS / "hopper.xml"), obs_dim=11, act_dim=3, healthy_z_min=0.7,
              healthy_angle_range=(-0.2, 0.2), healthy_state_range=(-100.0, 100.0))
WALKER = dict(xml=str(ASSETS / "walker2d_v5.xml"), obs_dim=17, act_dim=6, healthy_z_min=0.8, healthy_z_max=2.0,
              healthy_angle_range=(-1.0, 1.0))


def mjcf_spec(**fields) -> MjcfSpec:
    return MjcfSpec(name="x", family="mjcf", **fields)


def run_both(gym_id: str, fields: dict, seed: int, steps: int, action_scale: float):
    """Step gymnasium's env and ours on the same seed and actions, episode after episode, and compare."""
    ref = gym.make(gym_id, disable_env_checker=True).unwrapped  # no TimeLimit: episodes here end long before
    ours = make_env(mjcf_spec(**fields))
    rng = np.random.default_rng(seed)
    terminations = 0
    obs_ref, _ = ref.reset(seed=seed)
    obs, _ = ours.reset(seed=seed)
    np.testing.assert_allclose(obs, obs_ref, rtol=1e-12, atol=1e-12)
    for t in range(steps):
        action = (action_scale * rng.standard_normal(ref.action_space.shape)).astype(np.float32)
        obs_ref, r_ref, term_ref, _, _ = ref.step(action)
        obs, r, term, trunc, _ = ours.step(action)
        np.testing.assert_allclose(obs, obs_ref, rtol=1e-12, atol=1e-12, err_msg=f"step {t}")
        assert r == pytest.approx(r_ref, rel=1e-9, abs=1e-9), f"step {t}"
        assert term == term_ref, f"step {t}"
        assert not trunc
        if term:
            terminations += 1
            obs_ref, _ = ref.reset(seed=seed + terminations)
            obs, _ = ours.reset(seed=seed + terminations)
            np.testing.assert_allclose(obs, obs_ref, rtol=1e-12, atol=1e-12)
    ref.close()
    ours.close()
    return terminations


@pytest.mark.parametrize(("gym_id", "fields"), [("Hopper-v5", HOPPER), ("Walker2d-v5", WALKER)])
def test_mjcf_matches_gymnasium_step_for_step(gym_id, fields):
    # strong random actions make episodes end (falls): terminations are compared too, and resets after them
    terminations = run_both(gym_id, fields, seed=3, steps=600, action_scale=1.0)
    assert terminations >= 3


def test_mjcf_spec_records_every_term_and_resolves_the_xml_beside_it(tmp_path):
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "h.xml").write_bytes((ASSETS / "hopper.xml").read_bytes())
    (tmp_path / "h.toml").write_text('name = "h"\nfamily = "mjcf"\nxml = "models/h.xml"\nobs_dim = 11\nact_dim = 3\n')
    spec = load_spec_file(tmp_path / "h.toml")
    env = make_env(spec)
    assert env.observation_space.shape == (11,) and env.action_space.shape == (3,)
    terms = spec.model_dump()
    for key in ("forward_axis", "frame_skip", "forward_reward_weight", "ctrl_cost_weight", "contact_cost_weight",
                "healthy_reward", "healthy_z_min", "healthy_angle_range", "healthy_state_range",
                "reset_noise_scale", "qvel_clip", "contact_forces", "max_episode_steps", "torso"):
        assert key in terms
    assert terms["frame_skip"] == 4 and terms["qvel_clip"] == 10.0


def test_mjcf_contact_forces_join_the_observation(tmp_path):
    # Ant's body (free root): 15 qpos - 2 + 14 qvel + 6 * 13 bodies (the world's row left out, as Ant-v5)
    env = make_env(mjcf_spec(xml=str(ASSETS / "ant.xml"), obs_dim=105, act_dim=8, frame_skip=5, contact_forces=True,
                             contact_cost_weight=5e-4, ctrl_cost_weight=0.5, healthy_z_min=0.2,
                             healthy_z_max=1.0, qvel_clip=None))
    obs, _ = env.reset(seed=0)
    assert obs.shape == (105,)
    assert env.unwrapped.root.kind == "free"
    obs, reward, *_ = env.step(env.action_space.sample())
    assert np.isfinite(reward) and np.abs(obs[-78:]).max() <= 1.0


@pytest.mark.parametrize(("fields", "message"), [
    (dict(xml="/no/such/file.xml", obs_dim=1, act_dim=1), "no such file"),
    (dict(xml=str(ASSETS / "hopper.xml"), obs_dim=11, act_dim=3, torso="nobody"), "no body named 'nobody'"),
    (dict(xml=str(ASSETS / "ant.xml"), obs_dim=27, act_dim=8, healthy_angle_range=(-1, 1)), "exactly one hinge"),
    (dict(xml=str(ASSETS / "hopper.xml"), obs_dim=12, act_dim=3), "spec says obs 12"),
])
def test_mjcf_spec_errors_are_one_line(fields, message):
    with pytest.raises(MiktError, match=message) as info:
        make_env(mjcf_spec(**fields))
    assert "\n" not in str(info.value)


def test_mjcf_spec_values_are_checked():
    with pytest.raises(ValueError, match="forward_axis must not be zero"):
        mjcf_spec(xml="a.xml", obs_dim=1, act_dim=1, forward_axis=(0, 0, 0))
    with pytest.raises(ValueError, match="healthy_angle_range"):
        mjcf_spec(xml="a.xml", obs_dim=1, act_dim=1, healthy_angle_range=(1, -1))
    with pytest.raises(MiktError, match="not read from a file"):
        mjcf_spec(xml="a.xml", obs_dim=1, act_dim=1).xml_path()


def test_unnamed_actuators_are_named_after_what_they_drive_and_odd_names_read(tmp_path):
    import mujoco

    from miktcli.envs.factory import actuator_name
    from miktcli.envs.mjcf import body_name

    xml = ('<mujoco><worldbody><body name="b"><joint name="hip" type="hinge"/><geom size="0.1"/>'
           '<site name="s1"/><body name="c"><joint name="knee" type="hinge"/>'
           '<geom type="capsule" size="0.1" fromto="0 0 0 0 0 1"/><site name="s2" pos="0 0 1"/></body></body>'
           '</worldbody><tendon><spatial name="tnd"><site site="s1"/><site site="s2"/></spatial></tendon>'
           '<actuator><motor site="s1" gear="1 0 0 0 0 0"/><motor tendon="tnd"/><motor joint="knee"/>'
           '<motor name="own" joint="hip"/></actuator></mujoco>')
    m = mujoco.MjModel.from_xml_string(xml)
    assert [actuator_name(m, i) for i in range(m.nu)] == ["s1", "tnd", "knee", "own"]
    path = tmp_path / "latin.xml"  # a name written by an older tool in ISO-8859-1, not UTF-8
    path.write_bytes('<mujoco><worldbody><body name="b\xe9"><geom size="0.1"/></body></worldbody></mujoco>'
                     .encode("latin-1"))
    assert body_name(mujoco.MjModel.from_xml_path(str(path)), 1) == "b\ufffd"
