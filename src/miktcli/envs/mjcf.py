"""The `mjcf` family: any legged body from an MJCF file, with the locomotion task of gymnasium's Hopper-v5,
Walker2d-v5 and Ant-v5, computed straight from MjData with numpy (no wrapper stack in the hot path).

With a spec's defaults and the Hopper/Walker2d weights, an env built from gymnasium's own hopper.xml or
walker2d_v5.xml matches Hopper-v5 / Walker2d-v5 step for step (tests/test_mjcf.py). Per env step:

- root: the torso's root joint — a free joint, or the torso's slide joints (planar walkers: rootx, rootz) and
  its hinge (rooty). Its position p is the free joint's (x, y, z), or the torso's reference position plus each
  slide's displacement along its axis (read at the reference pose).
- observation: qpos without the root's horizontal coordinates (a free root's x, y; slides with no vertical
  component), then qvel clipped to ±qvel_clip (Hopper's ±10; none: unclipped), then, with contact_forces, the
  cfrc_ext rows of every body but the world (always zero), clipped to contact_force_range (Ant-v5's layout).
- reward: forward_reward_weight · (p_after − p_before)·forward_axis / dt
          + healthy_reward if the step ends healthy
          − ctrl_cost_weight · Σ action² (the raw action; MuJoCo clamps ctrl to ctrlrange)
          − contact_cost_weight · Σ clipped cfrc_ext² (over the same rows as the observation)
- healthy: qpos and qvel finite, and strictly inside each range the spec sets (healthy_z_min/max on p_z,
  healthy_angle_range on the root hinge, healthy_state_range on every qpos and qvel entry but the root position).
  Not healthy → terminated (when terminate_when_unhealthy). A simulation MuJoCo had to reset (NaN/Inf) also
  terminates. The time limit truncates.
- reset: qpos = qpos0 + U(−s, s), qvel = U(−s, s), s = reset_noise_scale, in gymnasium's draw order; with
  `keyframe`, the keyframe's qpos and qvel take the place of qpos0 and 0.
- action: with `action_map = "raw"` (the default) the action is ctrl; with "ctrlrange" an action in [−1, 1]
  spans each actuator's ctrlrange around its centre (CtrlMap). The control cost is on the action either way.
- model edits: `remove` deletes bodies or geoms, `floor` adds a ground plane (edited_model); with neither, the
  XML is compiled as it is.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from miktcli import limits
from miktcli.envs.spec import MjcfSpec
from miktcli.errors import MiktError

# MuJoCo replaces a diverged (NaN/Inf) state with a reset state and counts a warning (as in centipede.py).
_DIVERGENCE_WARNINGS = (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
                        mujoco.mjtWarning.mjWARN_BADQACC)
_JOINT = mujoco.mjtJoint
_JOINT_TRANSMISSIONS = (int(mujoco.mjtTrn.mjTRN_JOINT), int(mujoco.mjtTrn.mjTRN_JOINTINPARENT))


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def model_files(xml: Path) -> list[Path]:
    """Every file the model loads besides itself, as absolute paths (MuJoCo's rules: includes relative to the
    main file's folder; meshes, height fields and skins under meshdir; textures under texturedir). Each one,
    the XML too, must be a regular file within MAX_MODEL_FILE_BYTES, and all of them together within
    MAX_MODEL_BYTES, before MuJoCo (which reads them whole, and would wait on a FIFO) opens any."""
    base = xml.parent
    found: list[Path] = []
    total = len(_bounded_model_file(xml, 0))
    pending = [xml]
    while pending:  # includes may include
        current = pending.pop()
        data = _bounded_model_file(current, total) if current != xml else _bounded_model_file(xml, 0)
        try:
            tree = ET.fromstring(data)
        except ET.ParseError as err:
            raise MiktError(f"{xml}: not a valid MJCF model: {err}") from err
        for node in tree.iter("include"):
            if node.get("file"):
                path = base / node.get("file")
                if path not in found:
                    found.append(path)
                    total += len(_bounded_model_file(path, total))
                    pending.append(path)
    try:
        spec = mujoco.MjSpec.from_file(str(xml))
    except ValueError as err:
        raise MiktError(f"{xml}: not a valid MJCF model: {_one_line(err)}") from err

    def under(folder: str, name: str) -> Path:
        path = Path(name)
        return path if path.is_absolute() else base / folder / path

    assets = [under(spec.meshdir, a.file) for a in [*spec.meshes, *spec.hfields, *spec.skins] if a.file]
    for texture in spec.textures:
        assets += [under(spec.texturedir, n) for n in [texture.file, *getattr(texture, "cubefiles", [])] if n]
    for path in dict.fromkeys(assets):
        if path not in found:
            total += _model_file_size(path, total)
            found.append(path)
    # sub-models (<asset><model file=…/>, placed with <attach>) and, recursively, what they load
    for sub in _submodel_files(xml, base):
        for path in [sub, *model_files(sub)]:
            if path not in found:
                total += _model_file_size(path, total)
                found.append(path)
    return found


def _model_elements(xml: Path) -> list[ET.Element]:
    return list(ET.fromstring(limits.read_file_bounded(xml, str(xml), limits.MAX_MODEL_FILE_BYTES)).iter())


def _submodel_files(xml: Path, base: Path) -> list[Path]:
    return [base / node.get("file") for node in _model_elements(xml)
            if node.tag == "model" and node.get("file")]


def absolute_references(xml: Path) -> list[str]:
    """The files the XML (not its includes) names by an absolute path."""
    return [node.get("file") for node in _model_elements(xml)
            if node.get("file") and Path(node.get("file")).is_absolute()]


def _model_file_size(path: Path, total_before: int) -> int:
    """A model file's size, refused unless it is a regular file within both bounds."""
    import os

    with limits.open_regular(path, str(path)) as f:
        size = os.fstat(f.fileno()).st_size
    limits.check_declared_size(str(path), size, limits.MAX_MODEL_FILE_BYTES)
    if total_before + size > limits.MAX_MODEL_BYTES:
        raise MiktError(f"{path}: the model's files pass {limits.MAX_MODEL_BYTES:,} bytes together",
                        hint=limits.LIMITS_HINT)
    return size


def _bounded_model_file(path: Path, total_before: int) -> bytes:
    _model_file_size(path, total_before)
    return limits.read_file_bounded(path, str(path), limits.MAX_MODEL_FILE_BYTES)


def load_model(path: Path) -> mujoco.MjModel:
    """Parse and compile an MJCF file; any failure is one MiktError naming the file and the problem."""
    path = Path(path)
    if not path.exists():
        raise MiktError(f"{path}: no such file")
    model_files(path)  # regular files within the bounds, or one line before MuJoCo reads any
    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except ValueError as err:  # MuJoCo's parser and compiler errors, several lines long
        raise MiktError(f"{path}: not a valid MJCF model: {_one_line(err)}") from err


def edited_model(path: Path, floor: bool, remove: list[str]) -> mujoco.MjModel:
    """The model with the spec's edits: the named bodies and geoms deleted, a ground plane added. With no edit
    it is `load_model(path)` itself (MjSpec compiles the same model, but the plain path stays the plain path)."""
    if not floor and not remove:
        return load_model(path)
    load_model(path)  # the same checks and one-line errors as an unedited model
    spec = mujoco.MjSpec.from_file(str(path))
    for name in remove:
        element = spec.body(name) or spec.geom(name)
        if element is None or element == spec.worldbody:
            bodies = ", ".join(b.name for b in spec.bodies if b.name and b != spec.worldbody)
            raise MiktError(f"{path}: remove: no body or geom named '{name}' (bodies: {bodies or 'none'})")
        spec.delete(element)
    if floor:
        plane = spec.worldbody.add_geom(name="mikt-floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05])
        plane.rgba = [0.45, 0.5, 0.55, 1]
    try:
        return spec.compile()
    except ValueError as err:
        raise MiktError(f"{path}: the model does not compile with remove = {remove}: {_one_line(err)}") from err


_NAME_ADDRESS = {mujoco.mjtObj.mjOBJ_BODY: "name_bodyadr", mujoco.mjtObj.mjOBJ_JOINT: "name_jntadr",
                 mujoco.mjtObj.mjOBJ_ACTUATOR: "name_actuatoradr", mujoco.mjtObj.mjOBJ_TENDON: "name_tendonadr",
                 mujoco.mjtObj.mjOBJ_SITE: "name_siteadr"}


def object_name(m: Any, kind: mujoco.mjtObj, i: int) -> str:
    """An object's name, '' when it has none; a name that is not UTF-8 (ISO-8859-1 from an older tool) is
    read with its odd bytes replaced instead of failing."""
    try:
        return mujoco.mj_id2name(m, kind, i) or ""
    except UnicodeDecodeError:
        start = int(getattr(m, _NAME_ADDRESS[kind])[i])
        raw = bytes(m.names[start:]).split(b"\0", 1)[0]
        return raw.decode("utf-8", errors="replace")


def body_name(model: mujoco.MjModel, body: int) -> str:
    return object_name(model, mujoco.mjtObj.mjOBJ_BODY, body) or f"body{body}"


@dataclass(frozen=True)
class Root:
    """How the robot's torso is attached to the world."""

    body: int
    kind: str  # "free" or "slide"
    joints: tuple[int, ...]  # the torso's joints
    position_qpos: tuple[int, ...]  # qpos entries of the root position (free: x, y, z; else the slides)
    slide_axes: np.ndarray  # (n_slides, 3) world axes at the reference pose; empty for a free root
    horizontal_qpos: tuple[int, ...]  # qpos entries the observation drops
    hinge_qpos: int | None  # the torso's single hinge, if it has exactly one (its angle: healthy_angle_range)

    def describe(self, model: mujoco.MjModel) -> str:
        names = ", ".join(model.joint(j).name or f"joint{j}" for j in self.joints)
        return f"{body_name(model, self.body)} ({self.kind} root: {names})"


def _has_jointed_ancestor(model: mujoco.MjModel, body: int) -> bool:
    parent = int(model.body_parentid[body])
    while parent > 0:
        if model.body_jntnum[parent] > 0:
            return True
        parent = int(model.body_parentid[parent])
    return False


def find_root(model: mujoco.MjModel, torso: str | None = None) -> Root:
    """The torso and its root joint. Default torso: the body of the first free joint that carries actuated
    joints below it (a free ball or box is not the robot), else the first body (in model order) with slide
    joints and no jointed ancestor; with no free body carrying actuators, the first free joint's body."""
    if torso is not None:
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, torso)
        if body < 1:
            raise MiktError(f"no body named '{torso}' (bodies: "
                            + ", ".join(body_name(model, b) for b in range(1, model.nbody)) + ")")
        candidates = [body]
    else:
        free = [int(model.jnt_bodyid[j]) for j in range(model.njnt) if model.jnt_type[j] == _JOINT.mjJNT_FREE]
        slide = [b for b in range(1, model.nbody) if not _has_jointed_ancestor(model, b)
                 and any(model.jnt_type[j] == _JOINT.mjJNT_SLIDE for j in _body_joints(model, b))]
        driven = _actuated_bodies(model)
        candidates = [b for b in free if _subtree_holds(model, b, driven)][:1] or slide[:1] or free[:1]
    if not candidates:
        raise MiktError("no free or slide root joint: the body cannot move through the world")
    body = candidates[0]
    joints = _body_joints(model, body)
    types = [int(model.jnt_type[j]) for j in joints]
    if _JOINT.mjJNT_FREE in types:
        adr = int(model.jnt_qposadr[joints[types.index(_JOINT.mjJNT_FREE)]])
        return Root(body, "free", tuple(joints), (adr, adr + 1, adr + 2), np.zeros((0, 3)), (adr, adr + 1),
                    None)
    slides = [j for j, t in zip(joints, types, strict=True) if t == _JOINT.mjJNT_SLIDE]
    if not slides or _has_jointed_ancestor(model, body):
        raise MiktError(f"body '{body_name(model, body)}' has no free or slide root joint")
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)  # the reference pose: the slides' world axes there
    axes = np.array([data.xaxis[j] for j in slides])
    hinges = [j for j, t in zip(joints, types, strict=True) if t == _JOINT.mjJNT_HINGE]
    horizontal = tuple(int(model.jnt_qposadr[j]) for j, a in zip(slides, axes, strict=True) if a[2] == 0.0)
    return Root(body, "slide", tuple(joints), tuple(int(model.jnt_qposadr[j]) for j in slides), axes,
                horizontal, int(model.jnt_qposadr[hinges[0]]) if len(hinges) == 1 else None)


def _actuated_bodies(model: mujoco.MjModel) -> set[int]:
    """Bodies whose joints an actuator drives directly (joint transmissions)."""
    joints = [int(model.actuator_trnid[i, 0]) for i in range(model.nu)
              if int(model.actuator_trntype[i]) in _JOINT_TRANSMISSIONS]
    return {int(model.jnt_bodyid[j]) for j in joints}


def _subtree_holds(model: mujoco.MjModel, root: int, bodies: set[int]) -> bool:
    """Whether one of `bodies` is `root` or lies below it; true as well when no actuator drives a joint
    directly (tendon or site transmissions), so that such a model keeps the first free body."""
    if not bodies:
        return True
    for body in bodies:
        while body > 0:
            if body == root:
                return True
            body = int(model.body_parentid[body])
    return False


def _body_joints(model: mujoco.MjModel, body: int) -> list[int]:
    start = int(model.body_jntadr[body])
    return list(range(start, start + int(model.body_jntnum[body]))) if start >= 0 else []


def _keyframe_id(model: mujoco.MjModel, spec: MjcfSpec) -> int | None:
    if spec.keyframe is None:
        return None
    key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, spec.keyframe)
    if key < 0:
        names = [object_name(model, mujoco.mjtObj.mjOBJ_KEY, k) or f"#{k}" for k in range(model.nkey)]
        raise MiktError(f"environment '{spec.name}': keyframe: the model has no keyframe named '{spec.keyframe}' "
                        f"(keyframes: {', '.join(names) or 'none'})")
    return key


def is_position_actuator(model: mujoco.MjModel, i: int) -> bool:
    """A servo: force = kp·(ctrl − length) (− kv·velocity), so ctrl is a target length (a joint angle)."""
    kp = float(model.actuator_gainprm[i, 0])
    return (int(model.actuator_biastype[i]) == int(mujoco.mjtBias.mjBIAS_AFFINE) and kp > 0
            and float(model.actuator_biasprm[i, 1]) == -kp and float(model.actuator_biasprm[i, 0]) == 0.0)


@dataclass(frozen=True)
class CtrlMap:
    """`action_map = "ctrlrange"`: an action in [-1, 1] onto each actuator's ctrlrange, piecewise linear so that
    −1, 0 and 1 reach its low end, its centre and its high end. The centre of a position actuator is its
    length at the reset pose (a zero action holds that pose); of any other, the middle of its range. An
    actuator with no ctrlrange (ctrllimited off) gets the action as it is."""

    low: np.ndarray
    centre: np.ndarray
    high: np.ndarray
    limited: np.ndarray  # bool per actuator

    @classmethod
    def of(cls, model: mujoco.MjModel, qpos: np.ndarray) -> CtrlMap:
        data = mujoco.MjData(model)
        data.qpos[:] = qpos
        # actuator_length at the reset pose, without the collision pass (a model MuJoCo cannot simulate is
        # refused by `envs add`'s first step in one line, not here)
        for stage in (mujoco.mj_kinematics, mujoco.mj_comPos, mujoco.mj_tendon, mujoco.mj_transmission):
            stage(model, data)
        low, high = model.actuator_ctrlrange[:, 0].copy(), model.actuator_ctrlrange[:, 1].copy()
        limited = model.actuator_ctrllimited.astype(bool) & (low < high)
        middle = (low + high) / 2
        servo = np.array([is_position_actuator(model, i) for i in range(model.nu)], dtype=bool)
        centre = np.clip(np.where(servo, data.actuator_length, middle), low, high)
        return cls(low, np.where(limited, centre, 0.0), high, limited)

    def __call__(self, action: np.ndarray) -> np.ndarray:
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        scaled = np.where(a >= 0, self.centre + a * (self.high - self.centre),
                          self.centre + a * (self.centre - self.low))
        return np.where(self.limited, scaled, action)


class MjcfEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"]}

    def __init__(self, spec: MjcfSpec, render_mode: str | None = None, width: int = 480, height: int = 480):
        path = spec.xml_path()
        try:
            self.model = edited_model(path, spec.floor, spec.remove)
        except MiktError as err:
            raise MiktError(f"environment '{spec.name}': {err}") from err
        m = self.model
        if m.nu == 0:
            raise MiktError(f"environment '{spec.name}': {path}: the model has no actuator")
        try:
            self.root = find_root(m, spec.torso)
        except MiktError as err:
            raise MiktError(f"environment '{spec.name}': {path}: {err}") from err
        if spec.healthy_angle_range is not None and self.root.hinge_qpos is None:
            raise MiktError(f"environment '{spec.name}': healthy_angle_range needs exactly one hinge joint on the "
                            f"torso '{body_name(m, self.root.body)}' (planar walkers: its pitch)")
        self.spec_ = spec
        self.data = mujoco.MjData(m)
        self.frame_skip = spec.frame_skip
        self.dt = m.opt.timestep * spec.frame_skip
        self.max_episode_steps = spec.max_episode_steps
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": int(np.round(1.0 / self.dt))}
        self._width, self._height = width, height
        self._renderer: mujoco.Renderer | None = None

        mujoco.mj_kinematics(m, self.data)
        self._reference_position = self.data.xpos[self.root.body].copy()
        self._position_qpos = np.array(self.root.position_qpos)
        self._qpos0_position = m.qpos0[self._position_qpos].copy()
        self._forward_axis = np.asarray(spec.forward_axis, dtype=np.float64)
        self._kept_qpos = np.array([i for i in range(m.nq) if i not in self.root.horizontal_qpos])
        # healthy_state_range covers gymnasium's state_vector() but for the root position (Hopper: [2:])
        self._state_entries = np.array([i for i in range(m.nq + m.nv) if i not in self.root.position_qpos])
        self._z_min = -np.inf if spec.healthy_z_min is None else spec.healthy_z_min
        self._z_max = np.inf if spec.healthy_z_max is None else spec.healthy_z_max

        obs_dim = len(self._kept_qpos) + m.nv + (6 * (m.nbody - 1) if spec.contact_forces else 0)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float64)
        self._key = _keyframe_id(m, spec)
        self._qpos_start = m.qpos0.copy() if self._key is None else m.key_qpos[self._key].copy()
        self._qvel_start = np.zeros(m.nv) if self._key is None else m.key_qvel[self._key].copy()
        self.ctrl_map = None if spec.action_map == "raw" else CtrlMap.of(m, self._qpos_start)
        if self.ctrl_map is None:
            bounds = m.actuator_ctrlrange.copy().astype(np.float32)
            self.action_space = gym.spaces.Box(low=bounds[:, 0], high=bounds[:, 1], dtype=np.float32)
        else:
            self.action_space = gym.spaces.Box(-1.0, 1.0, (m.nu,), dtype=np.float32)
        self._elapsed = 0

    # --- state ----------------------------------------------------------------------------------------
    def root_position(self) -> np.ndarray:
        q = self.data.qpos[self._position_qpos]
        if self.root.kind == "free":
            return q.copy()
        position = self._reference_position.copy()
        for axis, displacement in zip(self.root.slide_axes, q - self._qpos0_position, strict=True):
            position += displacement * axis
        return position

    def _forward_position(self) -> float:
        return float(self.root_position() @ self._forward_axis)

    def forward_position(self) -> float:
        """Where the body is along its direction of travel (what the forward reward differentiates)."""
        return self._forward_position()

    def contact_forces(self) -> np.ndarray:
        low, high = self.spec_.contact_force_range
        return np.clip(self.data.cfrc_ext[1:], low, high)

    def is_healthy(self) -> bool:
        s, d = self.spec_, self.data
        if not (np.isfinite(d.qpos).all() and np.isfinite(d.qvel).all()):
            return False
        if s.healthy_z_min is not None or s.healthy_z_max is not None:
            z = self.root_position()[2]
            if not self._z_min < z < self._z_max:
                return False
        if s.healthy_angle_range is not None:
            low, high = s.healthy_angle_range
            if not low < d.qpos[self.root.hinge_qpos] < high:
                return False
        if s.healthy_state_range is not None:
            low, high = s.healthy_state_range
            state = np.concatenate([d.qpos, d.qvel])[self._state_entries]
            if not np.all(np.logical_and(low < state, state < high)):
                return False
        return True

    def _obs(self) -> np.ndarray:
        d, clip = self.data, self.spec_.qvel_clip
        qvel = d.qvel if clip is None else np.clip(d.qvel, -clip, clip)
        parts = [d.qpos[self._kept_qpos], qvel]
        if self.spec_.contact_forces:
            parts.append(self.contact_forces().ravel())
        return np.concatenate(parts)

    def _divergence_count(self) -> int:
        return sum(int(self.data.warning[w].number) for w in _DIVERGENCE_WARNINGS)

    # --- gymnasium API ------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        m, d, s = self.model, self.data, self.spec_.reset_noise_scale
        mujoco.mj_resetData(m, d)
        if self._key is not None:
            mujoco.mj_resetDataKeyframe(m, d, self._key)  # its act and ctrl too; qpos and qvel are set below
        qpos = self._qpos_start + self.np_random.uniform(low=-s, high=s, size=m.nq)  # gymnasium's draw order
        qvel = self._qvel_start + self.np_random.uniform(low=-s, high=s, size=m.nv)
        d.qpos[:], d.qvel[:] = qpos, qvel
        mujoco.mj_forward(m, d)
        self._elapsed = 0
        return self._obs(), {"x_position": self._forward_position()}

    def step(self, action):
        after, velocity, forward, survive, ctrl_cost, contact_cost, reward, terminated = self._advance(action)
        self._elapsed += 1
        truncated = self._elapsed >= self.max_episode_steps and not terminated
        info = {"x_position": after, "x_velocity": velocity, "reward_forward": forward, "reward_ctrl": -ctrl_cost,
                "reward_contact": -contact_cost, "reward_survive": survive}
        return self._obs(), float(reward), terminated, truncated, info

    def _advance(self, action) -> tuple[float, float, float, float, float, float, float, bool]:
        """One step's physics and terms: (x after, velocity, forward, survive, ctrl cost, contact cost, reward,
        terminated). Shared by `step` and the lean stepper, so both compute the same bits."""
        s, m, d = self.spec_, self.model, self.data
        action = np.asarray(action)  # the cost is computed in the action's own dtype, as gymnasium does
        before = self._forward_position()
        diverged_before = self._divergence_count()
        d.ctrl[:] = action if self.ctrl_map is None else self.ctrl_map(action)
        mujoco.mj_step(m, d, nstep=self.frame_skip)
        mujoco.mj_rnePostConstraint(m, d)  # cfrc_ext is only filled by this call
        after = self._forward_position()
        velocity = (after - before) / self.dt
        forward = s.forward_reward_weight * velocity
        healthy = self.is_healthy()
        survive = healthy * s.healthy_reward
        # float(): the sums keep the action's dtype (float32 from a policy), the reward is float64 (as gymnasium's)
        ctrl_cost = float(s.ctrl_cost_weight * np.sum(np.square(action)))
        contact_cost = float(s.contact_cost_weight * np.sum(np.square(self.contact_forces()))) \
            if s.contact_cost_weight else 0.0
        reward = (forward + survive) - (ctrl_cost + contact_cost)  # gymnasium's rounding order
        terminated = self._divergence_count() > diverged_before or (not healthy and s.terminate_when_unhealthy)
        return after, velocity, forward, survive, ctrl_cost, contact_cost, reward, terminated

    def lean_stepper(self) -> MjcfStepper:
        """This env's step without gymnasium's wrappers and the info dict (see envs/lean.py)."""
        return MjcfStepper(self)

    def render(self):
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.model, self._height, self._width)
            self._camera = mujoco.MjvCamera()
            self._camera.type = mujoco.mjtCamera.mjCAMERA_TRACKING
            self._camera.trackbodyid = self.root.body
            self._camera.distance = 2.5 * max(1.0, self._body_size())
            self._camera.elevation = -20
            self._camera.azimuth = 90
        self._renderer.update_scene(self.data, self._camera)
        return self._renderer.render()

    def _body_size(self) -> float:
        """The robot's size (its geoms' span, the floor left out): the model's own extent includes the floor."""
        m, d = self.model, self.data
        mine = m.geom_bodyid > 0
        if not mine.any():
            return 1.0
        low = (d.geom_xpos[mine] - m.geom_rbound[mine, None]).min(axis=0)
        high = (d.geom_xpos[mine] + m.geom_rbound[mine, None]).max(axis=0)
        return float((high - low).max())

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


class MjcfStepper:
    """`MjcfEnv.step` for SyncEnvs' lean path: the same `_advance` (so the same bits), the observation written
    in place, no info dict; the caller counts the time limit (`max_episode_steps`)."""

    def __init__(self, env: MjcfEnv):
        self.env = env
        self.max_episode_steps = env.max_episode_steps

    def step(self, action: np.ndarray, obs_out: np.ndarray) -> tuple[float, bool]:
        *_, reward, terminated = self.env._advance(action)
        obs_out[:] = self.env._obs()
        return float(reward), terminated
