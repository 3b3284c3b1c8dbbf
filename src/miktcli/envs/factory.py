"""Builds environments from specs, checks their dimensions, and registers them with gymnasium."""

from __future__ import annotations

import functools
import warnings
from typing import Any

import gymnasium as gym
import mujoco

from miktcli.envs.centipede import CentipedeEnv
from miktcli.envs.failures import remember_spec_name
from miktcli.envs.gl_backend import load_gl_backend
from miktcli.envs.mjcf import MjcfEnv, object_name
from miktcli.envs.mujoco_warnings import capture_mujoco_warnings
from miktcli.envs.spec import AnySpec, CentipedeSpec, GymnasiumSpec, MjcfSpec, load_spec, scan_specs
from miktcli.errors import EnvKeywordError, MiktError

Spec = AnySpec
GYM_NAMESPACE = "mikt"


def _check_continuous_mujoco(spec: Spec, env: gym.Env) -> None:
    """PPO here drives MuJoCo bodies with a Gaussian policy: a discrete or non-MuJoCo env cannot be used."""
    space = env.action_space
    problem = None
    if not isinstance(space, gym.spaces.Box) or len(space.shape) != 1:
        problem = f"its action space is {type(space).__name__}, not a continuous vector (Box)"
    elif not isinstance(env.observation_space, gym.spaces.Box) or len(env.observation_space.shape) != 1:
        problem = "its observation space is not a flat vector (Box)"
    elif not isinstance(getattr(env.unwrapped, "model", None), mujoco.MjModel):
        problem = "it is not a MuJoCo environment"
    if problem:
        env.close()
        raise MiktError(f"environment '{spec.name}': '{getattr(spec, 'id', spec.name)}' cannot be used: {problem}")


def env_dims(env: gym.Env) -> tuple[int, int]:
    return int(env.observation_space.shape[0]), int(env.action_space.shape[0])


def _build(spec: Spec, render_mode: str | None) -> gym.Env:
    """The environment of one spec, by its family. The specs are data; building them lives here, so that the
    environment modules can read their spec types without the specs importing them."""
    if isinstance(spec, CentipedeSpec):
        return CentipedeEnv(spec.legs, spec.crippled_legs, max_episode_steps=spec.max_episode_steps,
                            render_mode=render_mode, contact_readings=spec.contact_readings)
    if isinstance(spec, MjcfSpec):
        return MjcfEnv(spec, render_mode=render_mode)
    if isinstance(spec, GymnasiumSpec):
        return _make_gymnasium(spec, render_mode)
    raise TypeError(f"no builder for spec family {type(spec).__name__}")


def _make_gymnasium(spec: GymnasiumSpec, render_mode: str | None) -> gym.Env:
    with warnings.catch_warnings():
        # Ant-v4 with contact forces is deprecated upstream but is exactly the paper's Ant-v2 layout (111 dims).
        warnings.filterwarnings("ignore", message=".*is out of date.*")
        warnings.filterwarnings("ignore", category=DeprecationWarning)
        try:
            return gym.make(spec.id, max_episode_steps=spec.max_episode_steps, render_mode=render_mode,
                            disable_env_checker=True, **spec.kwargs)
        except gym.error.Error as err:
            raise MiktError(f"environment '{spec.name}': gymnasium cannot make '{spec.id}': {err}") from err
        except Exception as err:  # noqa: BLE001 - kwargs reach the env's own constructor, which may fail anyhow
            raise MiktError(f"environment '{spec.name}': '{spec.id}' fails with these kwargs: "
                            f"{type(err).__name__}: {err}") from err


class SpecName(str):
    """An environment's name bound to the spec it was resolved to (from the spec folders, or the copy a run or
    teacher carries: registry/carried.py). It reads, prints and serialises as the plain name, and `make_env`
    builds the spec it holds rather than whatever the spec folders hold under that name now, so every call
    that takes an env's name takes a resolved one."""

    spec: Spec

    def __new__(cls, spec: Spec) -> SpecName:
        named = super().__new__(cls, spec.name)
        named.spec = spec
        return named

    def __reduce__(self):  # pickled (a Ray worker) with its spec, which is rebuilt from its fields
        return SpecName, (self.spec,)


def make_env(spec: Spec | str, render_mode: str | None = None) -> gym.Env:
    """Build the environment a spec describes and check it has the dimensions the spec states. A name is
    looked up in the spec folders, unless it is a SpecName, which holds its spec."""
    if isinstance(spec, SpecName):
        spec = spec.spec
    elif isinstance(spec, str):
        spec = load_spec(spec)
    capture_mujoco_warnings()
    if render_mode is not None:
        load_gl_backend()
    env = _build(spec, render_mode)
    remember_spec_name(env, spec.name)
    _check_continuous_mujoco(spec, env)
    obs_dim, act_dim = env_dims(env)
    if (obs_dim, act_dim) != (spec.obs_dim, spec.act_dim):
        env.close()
        raise MiktError(
            f"environment '{spec.name}': spec says obs {spec.obs_dim} / act {spec.act_dim}, "
            f"the built model has obs {obs_dim} / act {act_dim}"
        )
    return env


def mujoco_model(env: gym.Env) -> Any:
    return env.unwrapped.model


# what an actuator drives, by its transmission type: the object its trnid names
_TRANSMITTED = {mujoco.mjtTrn.mjTRN_JOINT: mujoco.mjtObj.mjOBJ_JOINT,
                mujoco.mjtTrn.mjTRN_JOINTINPARENT: mujoco.mjtObj.mjOBJ_JOINT,
                mujoco.mjtTrn.mjTRN_TENDON: mujoco.mjtObj.mjOBJ_TENDON,
                mujoco.mjtTrn.mjTRN_SITE: mujoco.mjtObj.mjOBJ_SITE,
                mujoco.mjtTrn.mjTRN_BODY: mujoco.mjtObj.mjOBJ_BODY}


def actuator_name(m: Any, i: int) -> str:
    """An actuator's name, else the name of what it drives (joint, tendon, site, body), else actuator{i}."""
    own = object_name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, i)
    if own:
        return own
    target = _TRANSMITTED.get(mujoco.mjtTrn(int(m.actuator_trntype[i])))
    driven = object_name(m, target, int(m.actuator_trnid[i, 0])) if target is not None else ""
    return driven or f"actuator{i}"


def model_facts(env: gym.Env) -> dict[str, Any]:
    """Names of the bodies, joints and actuators of a MuJoCo-backed environment."""
    m = mujoco_model(env)
    return {
        "bodies": [object_name(m, mujoco.mjtObj.mjOBJ_BODY, i) or f"body{i}" for i in range(m.nbody)],
        "joints": [object_name(m, mujoco.mjtObj.mjOBJ_JOINT, i) or f"joint{i}" for i in range(m.njnt)],
        "actuators": [actuator_name(m, i) for i in range(m.nu)],
        "nq": int(m.nq),
        "nv": int(m.nv),
        "timestep": float(m.opt.timestep),
    }


# Registered envs leave the time limit to gymnasium's own TimeLimit wrapper (registered with the spec's limit),
# so `gym.make(..., max_episode_steps=N)` can lengthen an episode as well as shorten it.
_NO_INNER_LIMIT = 2**62


def make_registered(name: str, /, render_mode: str | None = None, **other: Any) -> gym.Env:
    """The entry point gymnasium calls for `mikt/NAME` (bound to NAME at registration, so no keyword of
    `gym.make` can swap the body: `name="ant"` once returned Ant under the centipede's id)."""
    if other:
        raise EnvKeywordError(f"gym.make('{GYM_NAMESPACE}/{name}'): keyword(s) {', '.join(sorted(other))} would change "
                        "the environment, which its spec fixes; gym.make takes max_episode_steps and render_mode",
                        hint="for another body or other settings, write a spec file (mikt envs --help)")
    spec = load_spec(name)
    return make_env(spec.model_copy(update={"max_episode_steps": _NO_INNER_LIMIT}), render_mode=render_mode)


def register_with_gymnasium() -> list[str]:
    """Register every valid spec as `mikt/NAME` (a bad spec file is reported by `mikt envs`; it never blocks
    the good ones). Importing `miktcli.gym` does this, so `gym.make("miktcli.gym:mikt/centipede-six")` works
    in a fresh interpreter; after that import, `gym.make("mikt/centipede-six")` works too."""
    ids = []
    for spec in scan_specs()[0]:
        env_id = f"{GYM_NAMESPACE}/{spec.name}"
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=functools.partial(make_registered, spec.name),
                         max_episode_steps=spec.max_episode_steps)
        ids.append(env_id)
    return ids


def forward_position(env: gym.Env) -> float | None:
    """Where an env's body is along its direction of travel: mikt's own families say it themselves; a
    gymnasium MuJoCo locomotion env's root x is its first qpos entry (Hopper's rootx, Ant's free joint). None
    for an env with neither."""
    base = env.unwrapped
    if hasattr(base, "forward_position"):
        return float(base.forward_position())
    data = getattr(base, "data", None)
    return float(data.qpos[0]) if data is not None and getattr(data, "qpos", None) is not None else None
