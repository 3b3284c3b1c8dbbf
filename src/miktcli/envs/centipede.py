"""The centipede environment: NerveNet's CentipedeEnv on the generated model, as a gymnasium Env."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from miktcli.envs.centipede_model import centipede_xml, torso_geom_ids

FRAME_SKIP = 5
HEIGHT_RANGE = (0.35, 1.15)  # every torso sphere's z must stay strictly inside
MAX_LATERAL_GAP = 0.45  # |y| gap between consecutive torsos
MAX_RESET_TRIES = 1000
# MuJoCo replaces a diverged (NaN/Inf) state with a reset state and counts a warning; those counters are how
# a non-finite state is still seen after mj_step.
_DIVERGENCE_WARNINGS = (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
                        mujoco.mjtWarning.mjWARN_BADQACC)


class CentipedeEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(
        self,
        legs: int,
        crippled_legs: list[int] | tuple[int, ...] = (),
        max_episode_steps: int = 1000,
        render_mode: str | None = None,
        width: int = 480,
        height: int = 480,
        contact_readings: str = "live",
    ):
        if contact_readings not in ("live", "zero"):
            raise ValueError(f"contact_readings must be 'live' or 'zero', got {contact_readings!r}")
        self.legs = legs
        # "zero" reproduces mujoco-py 2.x, where mj_step leaves cfrc_ext at 0 unless mj_rnePostConstraint runs
        # (CAT's published two-teacher runs never called it): the contact entries and the contact cost read 0.
        self.live_contacts = contact_readings == "live"
        self.torsos = legs // 2
        self.model = mujoco.MjModel.from_xml_string(centipede_xml(legs, crippled_legs))
        self.data = mujoco.MjData(self.model)
        self.dt = self.model.opt.timestep * FRAME_SKIP
        self.max_episode_steps = max_episode_steps
        self.render_mode = render_mode
        self._width, self._height = width, height
        self._renderer: mujoco.Renderer | None = None

        self._torso_geoms = np.array(torso_geom_ids(legs))
        self._front_body = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, f"torso_{self.torsos - 1}")
        self._updown_qpos = np.array(
            [self.model.jnt_qposadr[self.model.joint(f"bodyupdown_{j}").id] for j in range(1, self.torsos)]
        )
        # The legs count in the cost scale even when some are crippled (NerveNet's choice).
        self._ctrl_cost_weight = 0.5 * 4 / legs
        self._contact_cost_weight = 0.5e-3 * 4 / legs

        obs_dim = (self.model.nq - 2) + self.model.nv + 6 * self.model.nbody
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float64)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (self.model.nu,), np.float32)
        self._elapsed = 0

    # --- state checks -------------------------------------------------------------------------------
    def _divergence_count(self) -> int:
        return sum(int(self.data.warning[w].number) for w in _DIVERGENCE_WARNINGS)

    def is_healthy(self) -> bool:
        d = self.data
        if not (np.isfinite(d.qpos).all() and np.isfinite(d.qvel).all()):
            return False
        xpos = d.geom_xpos[self._torso_geoms]
        z = xpos[:, 2]
        if not ((z > HEIGHT_RANGE[0]) & (z < HEIGHT_RANGE[1])).all():
            return False
        return bool((np.abs(np.diff(xpos[:, 1])) < MAX_LATERAL_GAP).all())

    def contact_forces(self) -> np.ndarray:
        if not self.live_contacts:
            return np.zeros_like(self.data.cfrc_ext)
        return np.clip(self.data.cfrc_ext, -1.0, 1.0)

    def _obs(self) -> np.ndarray:
        d = self.data
        return np.concatenate([d.qpos[2:], d.qvel, self.contact_forces().ravel()])

    def front_x(self) -> float:
        return float(self.data.xpos[self._front_body, 0])

    def forward_position(self) -> float:
        """Where the body is along its direction of travel (what the forward reward differentiates)."""
        return self.front_x()

    # --- gymnasium API ------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        m, d, rng = self.model, self.data, self.np_random
        bound = 0.1 / (self.torsos - 1)
        for _ in range(MAX_RESET_TRIES):
            mujoco.mj_resetData(m, d)
            qpos = m.qpos0 + rng.uniform(-0.1, 0.1, m.nq)
            qpos[self._updown_qpos] = rng.uniform(-bound, bound, len(self._updown_qpos))
            qpos[5] = rng.uniform(-bound, bound)  # the root quaternion's y component, as NerveNet does
            d.qpos[:] = qpos
            d.qvel[:] = 0.1 * rng.standard_normal(m.nv)
            mujoco.mj_forward(m, d)
            if self.is_healthy():
                break
        else:  # pragma: no cover - the sampler accepts within a few tries for every shipped morphology
            raise RuntimeError("centipede reset found no healthy state")
        if self.live_contacts:
            mujoco.mj_rnePostConstraint(m, d)
        self._elapsed = 0
        return self._obs(), {}

    def step(self, action):
        m, d = self.model, self.data
        action = np.asarray(action, dtype=np.float64)
        x_before = self.front_x()
        diverged_before = self._divergence_count()
        d.ctrl[:] = action  # ctrllimited: MuJoCo clamps to [-1, 1]
        mujoco.mj_step(m, d, nstep=FRAME_SKIP)
        if self.live_contacts:
            mujoco.mj_rnePostConstraint(m, d)  # cfrc_ext is only filled by this call
        forward = (self.front_x() - x_before) / self.dt
        ctrl_cost = self._ctrl_cost_weight * float(np.square(action).sum())
        contact = self.contact_forces()
        contact_cost = self._contact_cost_weight * float(np.square(contact).sum())
        reward = forward - ctrl_cost - contact_cost + 1.0
        terminated = self._divergence_count() > diverged_before or not self.is_healthy()
        self._elapsed += 1
        truncated = self._elapsed >= self.max_episode_steps and not terminated
        obs = np.concatenate([d.qpos[2:], d.qvel, contact.ravel()])
        info = {"reward_forward": forward, "reward_ctrl": -ctrl_cost, "reward_contact": -contact_cost}
        return obs, reward, terminated, truncated, info

    def lean_stepper(self) -> CentipedeStepper:
        """This env's step over MjData views, bit-identical to `step` (see envs/lean.py)."""
        return CentipedeStepper(self)

    def render(self):
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.model, self._height, self._width)
            self._camera = mujoco.MjvCamera()
            self._camera.type = mujoco.mjtCamera.mjCAMERA_TRACKING
            self._camera.trackbodyid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, "torso_0")
            self._camera.distance = 2.5 + 0.5 * self.torsos
            self._camera.elevation = -25
            self._camera.azimuth = 120
        self._renderer.update_scene(self.data, self._camera)
        return self._renderer.render()

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


class CentipedeStepper:
    """`CentipedeEnv.step` over views of MjData made once (the same operations, order and dtypes), without
    the time limit (the caller counts it) and the info dict."""

    def __init__(self, env: CentipedeEnv):
        self.env, self.model, self.data = env, env.model, env.data
        self.max_episode_steps = env.max_episode_steps
        d = env.data
        self.front_x = d.xpos[env._front_body, 0:1]
        self.warnings = d.warning.number  # a live view
        self.divergence = np.array([int(w) for w in _DIVERGENCE_WARNINGS])
        self.live_contacts = env.live_contacts
        self.cfrc_ext, self.contact = d.cfrc_ext, np.zeros_like(d.cfrc_ext)  # stays 0 without live contacts
        self.qpos_tail, self.qvel = d.qpos[2:], d.qvel
        self.ctrl_w, self.contact_w = env._ctrl_cost_weight, env._contact_cost_weight
        self.nq, self.nv = self.qpos_tail.shape[0], self.qvel.shape[0]

    def step(self, action: np.ndarray, obs_out: np.ndarray) -> tuple[float, bool]:
        m, d = self.model, self.data
        action = np.asarray(action, dtype=np.float64)
        x_before = float(self.front_x[0])
        diverged_before = int(self.warnings[self.divergence].sum())
        d.ctrl[:] = action
        mujoco.mj_step(m, d, nstep=FRAME_SKIP)
        if self.live_contacts:
            mujoco.mj_rnePostConstraint(m, d)
            np.clip(self.cfrc_ext, -1.0, 1.0, out=self.contact)
        forward = (float(self.front_x[0]) - x_before) / self.env.dt
        ctrl_cost = self.ctrl_w * float(np.square(action).sum())
        contact = self.contact
        contact_cost = self.contact_w * float(np.square(contact).sum())
        reward = forward - ctrl_cost - contact_cost + 1.0
        terminated = int(self.warnings[self.divergence].sum()) > diverged_before or not self.env.is_healthy()
        a, b = self.nq, self.nq + self.nv
        obs_out[:a] = self.qpos_tail
        obs_out[a:b] = self.qvel
        obs_out[b:] = contact.reshape(-1)
        return reward, terminated
