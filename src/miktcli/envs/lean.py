"""The lean step: an env's step computed straight over MuJoCo's arrays, without gymnasium's per-step stack.

Gymnasium's MuJoCo envs spend ~30 µs per step in Python around `mj_step` (wrappers, named body lookups,
`state_vector` concatenations, an info dict); at a physics cost of ~160 µs per Ant step that is a fifth of the
rollout. A `LeanStepper` does the same arithmetic, in the same order and the same dtypes, over views of
`MjData` made once, so its observations, rewards and terminations are bit-identical to the env's own `step`
(tests/test_lean.py compares whole rollouts). The gymnasium env stays the reference: it still resets the
episode (its RNG, its noise), it is what evaluation and rendering use, and it is the path for any env
without a lean stepper (third-party gymnasium ids).

How an env family plugs in: give the env class a method `lean_stepper(self) -> LeanStepper` (the centipede
does), or, for a class this package does not own, register a factory with `register_lean_factory`.
A stepper computes one step's observation, reward and termination; the time limit stays with the caller
(`SyncEnvs` counts episode lengths), so a stepper only states the env's own limit, if it has one.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import gymnasium as gym
import mujoco
import numpy as np


class LeanStepper(Protocol):
    """One env's step over its MjModel/MjData, bit-identical to the env's `step` (minus the info dict)."""

    # The env's own time limit, where the env (not a TimeLimit wrapper) truncates; None when it has none.
    max_episode_steps: int | None

    def step(self, action: np.ndarray, obs_out: np.ndarray) -> tuple[float, bool]:
        """Apply `action`, advance the physics, write the next observation into `obs_out` (float64, in
        place) and return (reward, terminated)."""
        ...


LeanFactory = Callable[[Any], "LeanStepper | None"]
_FACTORIES: dict[type, LeanFactory] = {}
# Wrappers gym.make adds that change nothing a stepper computes: TimeLimit's limit is read off it and
# enforced by the caller; OrderEnforcing and the env checker only check call order and types.
_TRANSPARENT_WRAPPERS = (gym.wrappers.TimeLimit, gym.wrappers.OrderEnforcing, gym.wrappers.PassiveEnvChecker)


def register_lean_factory(env_class: type, factory: LeanFactory) -> None:
    """Give instances of exactly `env_class` (not its subclasses, which may override `step`) a lean step.
    `factory(unwrapped_env)` returns a stepper, or None where that instance's settings are not covered."""
    _FACTORIES[env_class] = factory


def lean_stepper(env: gym.Env) -> tuple[LeanStepper, int | None] | None:
    """The env's lean stepper and its episode limit (the tighter of a TimeLimit wrapper's and the env's own),
    or None where the env must be stepped through gymnasium (a wrapper that changes the data, a render mode
    that draws on every step, a class without a stepper)."""
    limit: int | None = None
    layer: Any = env
    while isinstance(layer, gym.Wrapper):
        if not isinstance(layer, _TRANSPARENT_WRAPPERS):
            return None
        if isinstance(layer, gym.wrappers.TimeLimit):
            limit = layer._max_episode_steps if limit is None else min(limit, layer._max_episode_steps)
        layer = layer.env
    if getattr(layer, "render_mode", None) == "human":
        return None
    own = getattr(type(layer), "lean_stepper", None)
    if own is not None:
        stepper = layer.lean_stepper()
    else:
        factory = _FACTORIES.get(type(layer))
        stepper = factory(layer) if factory else None
    if stepper is None:
        return None
    if stepper.max_episode_steps is not None:
        limit = stepper.max_episode_steps if limit is None else min(limit, stepper.max_episode_steps)
    return stepper, limit


class _MujocoStep:
    """What every gymnasium MujocoEnv's `do_simulation` does: ctrl, mj_step × frame_skip, and
    mj_rnePostConstraint (which fills cfrc_ext; kept for every env so MjData matches the reference's)."""

    max_episode_steps = None

    def __init__(self, env: Any):
        self.model, self.data = env.model, env.data
        self.frame_skip = int(env.frame_skip)
        self.dt = env.dt
        self.ctrl = self.data.ctrl
        self.qpos, self.qvel = self.data.qpos, self.data.qvel

    def simulate(self, action: np.ndarray) -> None:
        self.ctrl[:] = action
        mujoco.mj_step(self.model, self.data, nstep=self.frame_skip)
        mujoco.mj_rnePostConstraint(self.model, self.data)


class AntV4Stepper(_MujocoStep):
    """gymnasium's Ant-v4 (`AntEnv.step` and its properties, inlined in the same order and dtypes)."""

    def __init__(self, env: Any):
        super().__init__(env)
        self.torso_xy = self.data.xpos[env.model.body("torso").id, :2]
        self.cfrc_ext = self.data.cfrc_ext
        self.contact = np.empty_like(self.cfrc_ext)
        self.contact_low, self.contact_high = env._contact_force_range
        self.ctrl_w, self.contact_w = env._ctrl_cost_weight, env._contact_cost_weight
        self.healthy_reward, self.terminate = env._healthy_reward, env._terminate_when_unhealthy
        self.min_z, self.max_z = env._healthy_z_range
        self.use_contact = env._use_contact_forces
        self.skip = 2 if env._exclude_current_positions_from_observation else 0
        self.nq_obs = self.qpos.shape[0] - self.skip
        self.nv = self.qvel.shape[0]

    def step(self, action: np.ndarray, obs_out: np.ndarray) -> tuple[float, bool]:
        before = self.torso_xy.copy()
        self.simulate(action)
        velocity = (self.torso_xy - before) / self.dt
        qpos, qvel = self.qpos, self.qvel
        healthy = bool(np.isfinite(qpos).all() and np.isfinite(qvel).all()) and self.min_z <= qpos[2] <= self.max_z
        rewards = velocity[0] + float(healthy or self.terminate) * self.healthy_reward
        costs = self.ctrl_w * np.sum(np.square(action))  # float32 for a float32 action, as in the reference
        a, b = self.nq_obs, self.nq_obs + self.nv
        obs_out[:a] = qpos[self.skip:]
        obs_out[a:b] = qvel
        if self.use_contact:
            contact = np.clip(self.cfrc_ext, self.contact_low, self.contact_high, out=self.contact)
            costs += self.contact_w * np.sum(np.square(contact))
            obs_out[b:] = contact.reshape(-1)
        terminated = not healthy if self.terminate else False
        return rewards - costs, terminated


class HopperV5Stepper(_MujocoStep):
    """gymnasium's Hopper-v5 (`HopperEnv.step`, `_get_rew`, `is_healthy`, `_get_obs`)."""

    def __init__(self, env: Any):
        super().__init__(env)
        self.forward_w, self.ctrl_w = env._forward_reward_weight, env._ctrl_cost_weight
        self.healthy_reward, self.terminate = env._healthy_reward, env._terminate_when_unhealthy
        self.min_state, self.max_state = env._healthy_state_range
        self.min_z, self.max_z = env._healthy_z_range
        self.min_angle, self.max_angle = env._healthy_angle_range
        self.skip = 1 if env._exclude_current_positions_from_observation else 0
        self.nq_obs = self.qpos.shape[0] - self.skip
        self.state = np.empty(self.qpos.shape[0] - 2 + self.qvel.shape[0])

    def step(self, action: np.ndarray, obs_out: np.ndarray) -> tuple[float, bool]:
        qpos, qvel = self.qpos, self.qvel
        x_before = qpos[0]
        self.simulate(action)
        x_velocity = (qpos[0] - x_before) / self.dt
        a = self.nq_obs
        obs_out[:a] = qpos[self.skip:]
        np.clip(qvel, -10, 10, out=obs_out[a:])
        state = self.state  # state_vector()[2:]
        state[: qpos.shape[0] - 2] = qpos[2:]
        state[qpos.shape[0] - 2:] = qvel
        z, angle = qpos[1], qpos[2]
        healthy = all((np.all(np.logical_and(self.min_state < state, state < self.max_state)),
                       self.min_z < z < self.max_z, self.min_angle < angle < self.max_angle))
        rewards = self.forward_w * x_velocity + healthy * self.healthy_reward
        reward = rewards - self.ctrl_w * np.sum(np.square(action))
        return reward, (not healthy) and self.terminate


def _gymnasium_factories() -> None:
    from gymnasium.envs.mujoco.ant_v4 import AntEnv as AntV4
    from gymnasium.envs.mujoco.hopper_v5 import HopperEnv as HopperV5

    register_lean_factory(AntV4, AntV4Stepper)
    register_lean_factory(HopperV5, HopperV5Stepper)


_gymnasium_factories()
