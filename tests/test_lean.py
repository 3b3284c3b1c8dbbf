"""The lean step (envs/lean.py) against the gymnasium env it replaces: whole rollouts, bit for bit."""

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

import miktcli.gym  # noqa: F401 - registers mikt/NAME with gymnasium
from miktcli.envs import load_spec, make_env
from miktcli.envs.lean import lean_stepper
from miktcli.envs.spec import MjcfSpec
from miktcli.envs.vector import SyncEnvs

ASSETS = Path(gym.__file__).parent / "envs" / "mujoco" / "assets"


def spec_env(name, limit, **kwargs):
    spec = load_spec(name)
    update = {"max_episode_steps": limit}
    if kwargs:
        update["kwargs"] = {**spec.kwargs, **kwargs}
    return lambda: make_env(spec.model_copy(update=update))


def run(make, lean, steps, seed=7, num=2, scale=1.5):
    envs = SyncEnvs([make() for _ in range(num)], seed=seed, lean=lean)
    assert envs.lean is lean
    rng = np.random.default_rng(seed)
    act_dim = envs.action_low.shape[0]
    out = [envs.obs.copy()]
    for _ in range(steps):
        # float32 raw Gaussian-like samples beyond the action bounds, as the rollout sends them
        step = envs.step((rng.standard_normal((num, act_dim)) * scale).astype(np.float32))
        out.append((step.obs.copy(), step.rewards.copy(), step.terminated.copy(), step.truncated.copy(),
                    {i: o.copy() for i, o in step.final_obs.items()}, list(step.finished)))
    facts = envs.state()
    envs.close()
    return out, facts


def assert_identical(a, b):
    assert np.array_equal(a[0], b[0])
    for x, y in zip(a[1:], b[1:], strict=True):
        for u, v in zip(x[:4], y[:4], strict=True):
            assert u.dtype == v.dtype and np.array_equal(u, v)
        assert x[4].keys() == y[4].keys() and all(np.array_equal(x[4][k], y[4][k]) for k in x[4])
        assert x[5] == y[5]  # (return, length) of every finished episode, exactly


CASES = {
    "centipede-four": (spec_env("centipede-four", 30), 150),
    "cp-centipede-six": (spec_env("cp-centipede-six", 25), 120),
    "centipede-eight": (spec_env("centipede-eight", 20), 60),
    "centipede-eight-zero-contacts": (spec_env("centipede-eight-zero-contacts", 20), 60),
    "ant": (spec_env("ant", 25), 120),
    # a narrow healthy range so that Ant episodes also end by termination
    "ant-terminating": (spec_env("ant", 40, healthy_z_range=(0.45, 1.0)), 120),
    "hopper": (spec_env("hopper", 30), 200),
    "mikt/centipede-four (gym.make)": (lambda: gym.make("mikt/centipede-four", max_episode_steps=20), 80),
    # the mjcf family (your own robot): terminating walkers, and one that also ends on its own time limit
    "mjcf hopper": (lambda: make_env(MjcfSpec(name="h", family="mjcf", xml=str(ASSETS / "hopper.xml"), obs_dim=11,
                                              act_dim=3, healthy_z_min=0.7, healthy_angle_range=(-0.2, 0.2),
                                              max_episode_steps=11)), 150),
    "mjcf walker": (lambda: make_env(MjcfSpec(name="w", family="mjcf", xml=str(ASSETS / "walker2d_v5.xml"),
                                              obs_dim=17, act_dim=6, healthy_z_min=0.8, healthy_z_max=2.0,
                                              max_episode_steps=45)), 300),
}


@pytest.mark.parametrize("case", list(CASES))
def test_lean_rollout_is_bit_identical_to_gymnasium(case):
    make, steps = CASES[case]
    (lean, lean_facts), (ref, ref_facts) = run(make, True, steps), run(make, False, steps)
    assert_identical(lean, ref)
    terminated = sum(int(s[2].sum()) for s in ref[1:])
    truncated = sum(int(s[3].sum()) for s in ref[1:])
    assert truncated > 0 and (terminated > 0 or case.startswith(("ant", "mikt/", "centipede-eight"))), \
        (terminated, truncated)
    # the state a resume restores is the same too (lean keeps the elapsed count in its episode lengths)
    for key, value in ref_facts[0].items():
        assert np.array_equal(value, lean_facts[0][key]), key
    assert ref_facts[1] == lean_facts[1]


def test_an_ant_rollout_terminates_somewhere():
    make, steps = CASES["ant-terminating"]
    ref, _ = run(make, False, steps)
    assert sum(int(s[2].sum()) for s in ref[1:]) > 0


def test_envs_without_a_stepper_take_the_gymnasium_path():
    env = gym.make("Ant-v5")  # no lean stepper for v5: the reference path, which works for any id
    assert lean_stepper(env) is None
    assert SyncEnvs([env], seed=0).lean is False
    wrapped = gym.wrappers.TransformReward(make_env("centipede-four"), lambda r: 2 * r)  # changes the data
    assert lean_stepper(wrapped) is None
    assert lean_stepper(make_env("centipede-four")) is not None


def test_rollout_normaliser_matches_the_module_bit_for_bit():
    from miktcli.engine.nets import ObsNormalizer

    rng = np.random.default_rng(0)
    ref, fast_module = ObsNormalizer(111), ObsNormalizer(111)
    fast = fast_module.rollout(1)
    out = np.empty((1, 111), np.float32)
    for _ in range(300):
        obs = rng.standard_normal((1, 111)) * 5 + 2
        ref.update(obs)
        fast.update(obs)
        fast.normalize_into(obs, out)
        assert np.array_equal(out, ref.normalize_np(obs))
    for key, value in ref.state_dict().items():  # the statistics live in the module's buffers
        assert torch.equal(value, fast_module.state_dict()[key]), key


def test_scalar_reward_scaler_matches_the_array_path_bit_for_bit():
    from miktcli.engine.ppo import RewardScaler

    rng = np.random.default_rng(1)
    ref, fast = RewardScaler(1, 0.99, 10.0), RewardScaler(1, 0.99, 10.0)
    for t in range(500):
        reward, done = rng.standard_normal() * 3, t % 37 == 36
        scaled = ref(np.array([reward]), np.array([done]))
        assert fast.scale_one(reward, done) == scaled[0]
    for key, value in ref.state().items():
        assert torch.equal(value, fast.state()[key]), key


@pytest.mark.parametrize("activation", ["tanh", "relu"])
def test_rollout_forward_gives_the_same_bits_as_forward(activation):
    from miktcli.engine.policies import GaussianActorCritic

    agent = GaussianActorCritic(111, 8, activation=activation)
    x = torch.empty(1, 111)
    actor = agent.rollout_actor(x)
    with torch.inference_mode():
        for seed in range(50):
            x.copy_(torch.randn(1, 111, generator=torch.Generator().manual_seed(seed)) * 3)
            assert torch.equal(actor(), agent.action_mean(x))
