import mujoco
import numpy as np
import pytest

from miktcli.envs import load_all_specs, load_spec, make_env
from miktcli.envs.spec import load_spec_file
from miktcli.errors import MiktError

SHIPPED = {
    "centipede-four": (97, 10), "centipede-six": (139, 16), "centipede-eight": (181, 22),
    "cp-centipede-six": (139, 12), "cp-centipede-eight": (181, 18), "ant": (111, 8), "hopper": (11, 3),
    "centipede-eight-zero-contacts": (181, 22), "centipede-six-zero-contacts": (139, 16),
    "cp-centipede-eight-zero-contacts": (181, 18),
}


def write_spec(directory, name, body):
    path = directory / f"{name}.toml"
    path.write_text(f'name = "{name}"\n' + body)
    return path


def test_shipped_specs_build_with_their_dims():
    specs = {s.name: s for s in load_all_specs()}
    assert set(specs) == set(SHIPPED)
    for name, dims in SHIPPED.items():
        env = make_env(specs[name])
        obs, _ = env.reset(seed=0)
        assert (specs[name].obs_dim, specs[name].act_dim) == dims
        assert obs.shape == (dims[0],) and env.action_space.shape == (dims[1],)
        env.close()


@pytest.mark.parametrize("legs", [4, 6, 8, 10, 12, 14])
def test_any_even_leg_count_from_a_spec_file_alone(tmp_path, legs):
    for crippled, act in (([], 3 * legs - 2), ([0, 1], 3 * legs - 6)):
        path = write_spec(tmp_path, f"c{legs}", f'family = "centipede"\nlegs = {legs}\ncrippled_legs = {crippled}\n'
                          f"obs_dim = {21 * legs + 13}\nact_dim = {act}\n")
        env = make_env(load_spec_file(path))
        obs, _ = env.reset(seed=1)
        assert obs.shape == (21 * legs + 13,)
        model = env.unwrapped.model
        assert (model.nq, model.nv, model.nbody) == (3 * legs + 5, 3 * legs + 4, 5 * legs // 2 + 1)
        assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
        assert env.unwrapped.dt == pytest.approx(0.05)


def rollout(env, seed, steps=60):
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    traj = [obs]
    for _ in range(steps):
        obs, reward, term, trunc, _ = env.step(rng.uniform(-1, 1, env.action_space.shape))
        traj.append(np.append(obs, reward))
        if term or trunc:
            obs, _ = env.reset()
    return traj


def test_same_seed_same_trajectory():
    a, b = rollout(make_env("centipede-six"), 3), rollout(make_env("centipede-six"), 3)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    c = rollout(make_env("centipede-six"), 4)
    assert not np.array_equal(a[1], c[1])


def test_every_reset_passes_the_termination_checks():
    for name in ("centipede-four", "centipede-six", "cp-centipede-eight"):
        env = make_env(name).unwrapped
        for seed in range(15):
            env.reset(seed=seed)
            assert env.is_healthy()
            assert np.all(np.abs(env.data.qvel) < 1.0)


def test_each_termination_rule_fires():
    env = make_env("centipede-eight").unwrapped
    zero = np.zeros(env.action_space.shape)

    def step_from(edit):
        env.reset(seed=0)
        edit(env.data)
        mujoco.mj_forward(env.model, env.data)
        return env.step(zero)[2]

    assert not step_from(lambda d: None)
    assert step_from(lambda d: d.qpos.__setitem__(2, 3.0))  # torso far too high
    assert step_from(lambda d: d.qpos.__setitem__(2, 0.1))  # torso on the floor
    assert step_from(lambda d: d.qvel.__setitem__(0, np.nan))  # non-finite state
    # Turned 90° about z: consecutive torsos sit 0.5 apart in y (> 0.45), the direction rule fires.
    yaw90 = np.array([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])
    assert step_from(lambda d: d.qpos.__setitem__(slice(3, 7), yaw90))


def test_reward_terms_recomputed_from_the_simulator():
    env = make_env("centipede-six").unwrapped
    env.reset(seed=5)
    front = mujoco.mj_name2id(env.model, mujoco.mjtObj.mjOBJ_BODY, "torso_2")
    rng = np.random.default_rng(0)
    for _ in range(5):
        action = rng.uniform(-1.5, 1.5, env.action_space.shape)  # unclipped: the cost uses the raw action
        x0 = env.data.xpos[front, 0]
        _, reward, term, _, _ = env.step(action)
        forward = (env.data.xpos[front, 0] - x0) / 0.05
        ctrl = 0.5 * 4 / 6 * np.sum(action**2)
        contact = 0.5e-3 * 4 / 6 * np.sum(np.clip(env.data.cfrc_ext, -1, 1) ** 2)
        assert reward == pytest.approx(forward - ctrl - contact + 1.0, rel=1e-9, abs=1e-9)
        if term:
            break


def test_observation_layout():
    env = make_env("centipede-four").unwrapped
    obs, _ = env.reset(seed=0)
    d = env.data
    expected = np.concatenate([d.qpos[2:], d.qvel, np.clip(d.cfrc_ext, -1, 1).ravel()])
    assert np.array_equal(obs, expected)
    assert np.all(obs[-6 * env.model.nbody:][:6] == 0)  # the world body's contact row is kept (zeros)


def test_time_limit_truncates_and_does_not_terminate(tmp_path):
    path = write_spec(tmp_path, "short", 'family = "centipede"\nlegs = 8\nobs_dim = 181\nact_dim = 22\n'
                      "max_episode_steps = 12\n")
    env = make_env(load_spec_file(path))
    env.reset(seed=2)
    for t in range(12):
        _, _, term, trunc, _ = env.step(np.zeros(22))
        assert not term
        assert trunc == (t == 11)


@pytest.mark.slow  # process-level: runs mikt in a subprocess
def test_gymnasium_make_works_in_a_fresh_interpreter_without_importing_miktcli():
    import subprocess
    import sys

    script = (
        "import gymnasium as gym, numpy as np\n"
        "env = gym.make('miktcli.gym:mikt/centipede-eight', max_episode_steps=3)\n"
        "env.reset(seed=0)\n"
        "ends = [env.step(np.zeros(22))[3] for _ in range(3)]\n"
        "print(env.observation_space.shape[0], ends)\n"
        "long = gym.make('mikt/hopper', max_episode_steps=1500)\n"  # registered by the first make
        "print(long.spec.max_episode_steps, gym.make('mikt/centipede-four').spec.max_episode_steps)\n"
        "try:\n    gym.make('mikt/hopper', frobnicate=1)\nexcept TypeError as e:\n    print('refused')\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split("\n")[:3] == ["181 [False, False, True]", "1500 1000", "refused"]


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ('family = "centipede"\nlegs = 4\nact_dim = 10\n', "field 'obs_dim'"),
        ('family = "centipede"\nlegs = "four"\nobs_dim = 97\nact_dim = 10\n', "field 'legs'"),
        ('family = "centipede"\nlegs = 5\nobs_dim = 97\nact_dim = 10\n', "legs must be even"),
        ('family = "spider"\nlegs = 4\nobs_dim = 97\nact_dim = 10\n', "unknown family"),
        ('family = "centipede"\nlegs = 4\nobs_dim = 97\nact_dim = 10\ncolour = "red"\n', "field 'colour'"),
        ('family = "centipede"\nlegs = 4\nobs_dim = 97\nact_dim = 10\n[oops\n', "not valid TOML"),
    ],
)
def test_bad_spec_files_name_the_file_and_field(tmp_path, body, message):
    path = write_spec(tmp_path, "bad", body)
    with pytest.raises(MiktError, match=message) as info:
        load_spec_file(path)
    assert str(path) in str(info.value)


def test_dims_that_disagree_with_the_model(tmp_path):
    path = write_spec(tmp_path, "liar", 'family = "centipede"\nlegs = 4\nobs_dim = 100\nact_dim = 10\n')
    with pytest.raises(MiktError, match="spec says obs 100 / act 10, the built model has obs 97 / act 10"):
        make_env(load_spec_file(path))


def test_unknown_env_lists_the_known_ones():
    with pytest.raises(MiktError, match="unknown environment 'centipede-five'.*centipede-four"):
        load_spec("centipede-five")


def test_zero_contact_readings_change_the_observation_and_the_reward_only():
    """contact_readings = "zero" (CAT's mujoco-py 2.x runs): the same physics step for step, the contact entries
    and the contact cost at 0; and a live spec's fingerprint is the one it had before the field existed."""
    from miktcli.envs.fingerprint import spec_fingerprint, spec_record

    live_spec = load_spec("centipede-eight")
    zero_spec = live_spec.model_copy(update={"contact_readings": "zero"})
    assert "contact_readings" not in spec_record(live_spec)
    assert spec_fingerprint(zero_spec) != spec_fingerprint(live_spec)
    live, zero = make_env(live_spec), make_env(zero_spec)
    contact_from = live.unwrapped.model.nq - 2 + live.unwrapped.model.nv
    obs_l, _ = live.reset(seed=3)
    obs_z, _ = zero.reset(seed=3)
    assert np.array_equal(obs_l[:contact_from], obs_z[:contact_from]) and not obs_z[contact_from:].any()
    rng, live_contacts = np.random.default_rng(0), 0
    for _ in range(40):
        action = rng.uniform(-1, 1, live.action_space.shape)
        obs_l, r_l, term_l, trunc_l, info_l = live.step(action)
        obs_z, r_z, term_z, trunc_z, info_z = zero.step(action)
        assert np.array_equal(obs_l[:contact_from], obs_z[:contact_from]) and not obs_z[contact_from:].any()
        assert info_z["reward_contact"] == 0.0 and info_z["reward_forward"] == info_l["reward_forward"]
        assert r_z == pytest.approx(r_l - info_l["reward_contact"], abs=1e-12)
        assert (term_l, trunc_l) == (term_z, trunc_z)
        live_contacts += int(obs_l[contact_from:].any())
        if term_l:
            break
    assert live_contacts  # the live env did read contacts, on the steps the zero one read none
    live.close()
    zero.close()
