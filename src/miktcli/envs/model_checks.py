"""What a model's file says about the task it can make: facts `mikt envs add` decides the spec from and warns
about (no floor, a second free body, a height field, actuators with no ctrlrange). Pure reads of an MjModel."""

from __future__ import annotations

import mujoco
import numpy as np

from miktcli.envs.mjcf import Root, body_name, object_name

_GEOM = mujoco.mjtGeom


def has_floor(model: mujoco.MjModel, besides: list[str] = ()) -> bool:
    """Whether the world itself has a geom the robot can stand on (any collidable geom of the world body),
    the geoms named in `besides` left out."""
    world = model.geom_bodyid == 0
    collides = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
    others = np.array([object_name(model, mujoco.mjtObj.mjOBJ_GEOM, g) not in besides
                       for g in range(model.ngeom)], dtype=bool)
    return bool(np.any(world & collides & others))


def extra_free_bodies(model: mujoco.MjModel, root: Root) -> list[str]:
    """Bodies hung from the world by a free joint of their own, other than the robot's torso (a ball, a box):
    their state would be in the observation, and the task is the robot's."""
    names = []
    for j in range(model.njnt):
        body = int(model.jnt_bodyid[j])
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE and body != root.body and model.body_parentid[body] == 0:
            names.append(body_name(model, body))
    return names


def height_fields(model: mujoco.MjModel) -> list[str]:
    """World geoms that are height fields: their collisions cost time on every step."""
    return [object_name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}" for g in range(model.ngeom)
            if model.geom_type[g] == _GEOM.mjGEOM_HFIELD and model.geom_bodyid[g] == 0]


def unlimited_actuators(model: mujoco.MjModel) -> list[str]:
    """Actuators with no ctrlrange: the policy's action reaches them unscaled (a torque of ±1 × gear)."""
    from miktcli.envs.factory import actuator_name  # factory builds envs from this module's readers

    return [actuator_name(model, i) for i in range(model.nu)
            if not model.actuator_ctrllimited[i]
            or model.actuator_ctrlrange[i, 0] >= model.actuator_ctrlrange[i, 1]]


def keyframe_names(model: mujoco.MjModel) -> list[str]:
    return [object_name(model, mujoco.mjtObj.mjOBJ_KEY, k) for k in range(model.nkey)]


def torso_height(model: mujoco.MjModel, root: Root, qpos: np.ndarray) -> float:
    """The torso's height at a pose (the reset pose: the keyframe's, else qpos0)."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    return float(data.xpos[root.body][2])
