"""Generates the MJCF of a NerveNet centipede with L legs (facts: shared/reference/centipede.md).

Torso j >= 1 is nested inside torso j-1, so torso_0 is the rear and torso_{B-1} the front.
Each torso's legs are written before its child torso, which makes torso j's sphere geom index 1 + 5j.
"""

from __future__ import annotations

from xml.etree import ElementTree as ET

TORSO_RADIUS = 0.25
TORSO_SPACING = 0.50
LEG_RADIUS = 0.08
THIGH_Y = 0.28
SHIN_Y = 0.6
HIP_GEAR = 150
BODY_GEAR = 100


def torso_geom_ids(legs: int) -> list[int]:
    """Geom index of each torso sphere, rear to front (geom 0 is the floor)."""
    return [1 + 5 * j for j in range(legs // 2)]


def actuated_joints(legs: int, crippled_legs: list[int] | tuple[int, ...] = ()) -> list[str]:
    """Joint names in actuator order: hip_k, ankle_k per leg; body joints after each odd leg k > 1."""
    names: list[str] = []
    for k in range(legs):
        if k not in crippled_legs:
            names += [f"hip_{k}", f"ankle_{k}"]
        if k % 2 == 1 and k > 1:
            names += [f"body_{k // 2}", f"bodyupdown_{k // 2}"]
    return names


def _leg(parent: ET.Element, k: int) -> None:
    side = -1.0 if k % 2 == 0 else 1.0  # even legs on the left (-y), odd on the right (+y)
    thigh = ET.SubElement(parent, "body", name=f"legbody_{k}", pos=f"0 {side * THIGH_Y:g} 0")
    ET.SubElement(thigh, "joint", name=f"hip_{k}", type="hinge", pos="0 0 0", axis="0 0 1", range="-40 40")
    ET.SubElement(
        thigh, "geom", name=f"thigh_{k}", type="capsule", size=f"{LEG_RADIUS}",
        fromto=f"0 0 0 0 {side * THIGH_Y:g} 0",
    )
    foot = ET.SubElement(thigh, "body", name=f"frontFoot_{k}", pos=f"0 {side * THIGH_Y:g} 0")
    # The axis flips with the side so that a positive angle folds either foot down.
    ET.SubElement(
        foot, "joint", name=f"ankle_{k}", type="hinge", pos="0 0 0", axis=f"{-side:g} 0 0", range="30 100"
    )
    ET.SubElement(
        foot, "geom", name=f"shin_{k}", type="capsule", size=f"{LEG_RADIUS}",
        fromto=f"0 0 0 0 {side * SHIN_Y:g} 0",
    )


def centipede_xml(legs: int, crippled_legs: list[int] | tuple[int, ...] = ()) -> str:
    if legs < 4 or legs % 2:
        raise ValueError(f"a centipede needs an even number of legs >= 4, got {legs}")
    torsos = legs // 2
    root = ET.Element("mujoco", model=f"centipede_{legs}")
    ET.SubElement(root, "compiler", angle="degree", inertiafromgeom="true")
    ET.SubElement(root, "option", integrator="RK4", timestep="0.01")
    default = ET.SubElement(root, "default")
    ET.SubElement(default, "joint", armature="1", damping="1", limited="true")
    ET.SubElement(
        default, "geom", conaffinity="0", condim="3", density="25", friction="1.5 0.1 0.1",
        margin="0.01", rgba="0.8 0.6 0.4 1",
    )
    asset = ET.SubElement(root, "asset")
    ET.SubElement(
        asset, "texture", name="grid", type="2d", builtin="checker", rgb1="0.1 0.2 0.3", rgb2="0.2 0.3 0.4",
        width="512", height="512",
    )
    ET.SubElement(asset, "material", name="grid", texture="grid", texrepeat="20 20", reflectance="0.1")
    world = ET.SubElement(root, "worldbody")
    ET.SubElement(world, "light", pos="0 0 8", dir="0 0 -1", directional="true", diffuse="0.8 0.8 0.8")
    ET.SubElement(
        world, "geom", name="floor", type="plane", conaffinity="1", size="100 100 0.1", material="grid",
        rgba="0.8 0.9 0.8 1",
    )
    parent = world
    for j in range(torsos):
        pos = "0 0 0.75" if j == 0 else f"{TORSO_SPACING:g} 0 0"
        torso = ET.SubElement(parent, "body", name=f"torso_{j}", pos=pos)
        ET.SubElement(
            torso, "geom", name=f"torsoGeom_{j}", type="sphere", size=f"{TORSO_RADIUS}", density="100",
            rgba="0.7 0.5 0.3 1",
        )
        if j == 0:
            ET.SubElement(
                torso, "joint", name="root", type="free", pos="0 0 0", armature="0", damping="0",
                limited="false",
            )
        else:
            ET.SubElement(torso, "joint", name=f"body_{j}", type="hinge", pos="-0.25 0 0", axis="0 0 1",
                          range="-20 20")
            ET.SubElement(torso, "joint", name=f"bodyupdown_{j}", type="hinge", pos="-0.25 0 0", axis="0 1 0",
                          range="-10 30")
        _leg(torso, 2 * j)
        _leg(torso, 2 * j + 1)
        parent = torso
    actuator = ET.SubElement(root, "actuator")
    for joint in actuated_joints(legs, crippled_legs):
        gear = BODY_GEAR if joint.startswith("body") else HIP_GEAR
        ET.SubElement(actuator, "motor", joint=joint, gear=str(gear), ctrllimited="true", ctrlrange="-1 1")
    return ET.tostring(root, encoding="unicode")
