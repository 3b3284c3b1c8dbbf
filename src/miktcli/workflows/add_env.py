"""`mikt envs add`: turn an MJCF file into an `mjcf` spec in your spec folder.

The XML is copied into SPECS/NAME/ beside the spec, with every file it loads (includes, meshes, textures,
height fields, skins) at the same relative paths, so the spec keeps working after the original folder is moved
or deleted. A model that loads a file outside its own folder cannot be copied that way: its spec then names
the XML where it lies (an absolute path), and `AddedEnv.copied` is False so the CLI says so.

Everything is checked before anything is written; the copy is built once more from its new place; the spec
appears last, whole or not at all.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import mujoco

from miktcli.envs import model_checks
from miktcli.envs.factory import env_dims, model_facts
from miktcli.envs.mjcf import (
    MjcfEnv,
    Root,
    absolute_references,
    body_name,
    edited_model,
    find_root,
    load_model,
    model_files,
)
from miktcli.envs.mujoco_warnings import capture_mujoco_warnings, last_mujoco_warning, mujoco_warning_count
from miktcli.envs.probe import ProbeResult, probe
from miktcli.envs.spec import SPEC_NAME_RE, MjcfSpec, load_spec_file, spec_names, user_specs_dir
from miktcli.errors import MiktError
from miktcli.registry.files import write_bytes_atomic

# healthy_z_min of an added model: this fraction of the torso's height at the reset pose (gymnasium's Hopper,
# Walker2d and Humanoid stop at 0.56, 0.64 and 0.71 of theirs); no other health check.
HEALTHY_HEIGHT_FRACTION = 0.5
HOME_KEYFRAME = "home"  # MuJoCo Menagerie's name for the standing pose its legged robots start from
RANDOM_PROBE_EPISODES = 2


@dataclass(frozen=True)
class Note:
    """A choice `envs add` made from the model, or something that may spoil the task, with the spec key that
    changes it."""

    kind: str  # "chose" or "warning"
    text: str
    key: str


@dataclass
class AddedEnv:
    spec: MjcfSpec
    spec_path: Path
    xml_path: Path  # the XML the spec uses
    copied: bool  # False: the spec refers to the original XML in place
    files: list[str]  # files copied beside the XML (relative paths)
    root: str  # the chosen torso and its root joint, in words
    facts: dict
    why_in_place: str = ""  # when not copied: what keeps the model from being copied
    notes: list[Note] = field(default_factory=list)
    probes: list[ProbeResult] = field(default_factory=list)  # zero action, random actions, on the written spec


def check_simulates(env: MjcfEnv, xml: Path) -> None:
    """Reset the env and step it once, so that a model MuJoCo cannot simulate (its arena too small for its
    collision pass, say) is refused here in one line, not by every later command."""
    import numpy as np

    try:
        env.reset(seed=0)
        env.step(np.zeros(env.action_space.shape))
    except mujoco.FatalError as err:
        env.close()
        raise MiktError(f"{xml}: MuJoCo cannot simulate the model: {str(err).splitlines()[0]}",
                        hint="raise MuJoCo's memory for it (<size memory=\"…\"/>), or simplify the model") from None


def _relative(path: Path, folder: Path) -> Path | None:
    """`path` relative to `folder` by name, symlinks not followed (the copy must hold each file under the name
    the model uses), or None when it lies outside."""
    relative = Path(os.path.relpath(os.path.abspath(path), os.path.abspath(folder)))
    return None if relative.parts[:1] == ("..",) else relative


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a TOML basic string
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


def spec_toml(spec: MjcfSpec) -> str:
    """Every term written out (unset health checks as a comment), so the file documents the task."""
    dumped = spec.model_dump()
    first = ("name", "family", "xml", "torso", "obs_dim", "act_dim")
    data = {**{k: dumped[k] for k in first}, **{k: v for k, v in dumped.items() if k not in first}}
    unset = [k for k, v in data.items() if v is None]
    lines = [f"{k} = {_toml_value(v)}" for k, v in data.items() if v is not None]
    if unset:
        lines.append(f"# unset (no such check or bound; see `mikt envs show`): {', '.join(unset)}")
    return "\n".join(lines) + "\n"


def model_choices(model: mujoco.MjModel, root: Root) -> tuple[dict, list[Note]]:
    """The spec fields decided from the model's file alone, and what was decided or found, in words: the
    `home` keyframe as the reset pose, actions spanning each ctrlrange, a floor where there is none, other free
    bodies removed."""
    fields: dict = {"action_map": "ctrlrange"}
    notes = []
    keys = model_checks.keyframe_names(model)
    if HOME_KEYFRAME in keys:
        fields["keyframe"] = HOME_KEYFRAME
        notes.append(Note("chose", f"resets to the model's '{HOME_KEYFRAME}' keyframe", "keyframe"))
    elif keys:
        notes.append(Note("chose", f"resets to the default pose; the model's keyframes ({', '.join(keys)}) are "
                          "not used", "keyframe"))
    unlimited = model_checks.unlimited_actuators(model)
    if unlimited:
        notes.append(Note("warning", f"{len(unlimited)} actuator(s) have no ctrlrange ({', '.join(unlimited[:4])}"
                          f"{', …' if len(unlimited) > 4 else ''}): the policy's actions reach them unscaled; "
                          "give them a ctrlrange in the XML", "action_map"))
    if not model_checks.has_floor(model):
        fields["floor"] = True
        notes.append(Note("warning", "the model has no floor (the robot would fall into the void): adds a ground "
                          "plane at z = 0", "floor"))
    extra = model_checks.extra_free_bodies(model, root)
    if extra:
        notes.append(Note("warning", f"free bodies that are not the robot ({', '.join(extra)}) would be in the "
                          "observation: removes them", "remove"))
    fields_height = model_checks.height_fields(model)
    if fields_height and model_checks.has_floor(model, besides=fields_height):
        notes.append(Note("warning", f"height field(s) {', '.join(fields_height)} beside the floor: their "
                          "collisions cost time on every step: removes them", "remove"))
    else:
        fields_height = []  # the ground itself: kept
    if extra or fields_height:
        fields["remove"] = extra + fields_height
    return fields, notes


def reset_terms(model: mujoco.MjModel, root: Root, keyframe: str | None) -> dict:
    """healthy_z_min from the torso's height at the reset pose."""
    qpos = model.qpos0 if keyframe is None else model.key(keyframe).qpos
    height = model_checks.torso_height(model, root, qpos)
    return {"healthy_z_min": round(HEALTHY_HEIGHT_FRACTION * height, 3)} if height > 0 else {}


def survival_choice(env: MjcfEnv) -> tuple[dict, list[Note]]:
    """The healthy bonus off where a zero action lasts the whole episode: standing still would otherwise pay
    max_episode_steps × healthy_reward, more than walking earns early on."""
    standing = probe(env, "zero")
    if standing.fell[0]:
        return {}, []
    return {"healthy_reward": 0.0}, [Note(
        "chose", f"a zero action stands for the whole episode ({standing.lengths[0]} steps): no healthy bonus, so "
        "standing still earns nothing", "healthy_reward")]


def probe_notes(probes: list[ProbeResult], spec: MjcfSpec) -> list[Note]:
    if any(any(p.fell) for p in probes) or not spec.terminate_when_unhealthy:
        return []
    check = "no health check" if spec.healthy_z_min is None else f"root height > {spec.healthy_z_min}"
    return [Note("warning", f"no probe episode ended by the health check ({check}): the body may be unable to "
                 "fall, so 'healthy' never ends an episode; raise healthy_z_min", "healthy_z_min")]


def add_mjcf(xml: Path, name: str, torso: str | None = None, folder: Path | None = None) -> AddedEnv:
    """Check `xml`, then write SPECS/NAME.toml (and SPECS/NAME/ with the copied model). Raises MiktError, having
    written nothing, on any problem."""
    xml = Path(xml).expanduser()
    if not SPEC_NAME_RE.fullmatch(name):
        raise MiktError(f"invalid environment name '{name}': lowercase letters, digits, '.', '_' and '-'")
    if name.endswith(".toml"):  # its model folder NAME/ would read as a spec file to every later `mikt envs`
        raise MiktError(f"invalid environment name '{name}': it may not end in .toml",
                        hint=f"--name {name[:-len('.toml')] or 'my-robot'}")
    folder = Path(folder) if folder is not None else user_specs_dir()
    if name in spec_names():
        raise MiktError(f"environment '{name}' exists already", hint="choose another --name")
    target_toml, target_dir = folder / f"{name}.toml", folder / name
    for path in (target_toml, target_dir):
        if path.exists():
            raise MiktError(f"{path} exists already", hint="choose another --name, or remove it")
    capture_mujoco_warnings()  # the compiler's warnings become one note, not a line per compilation
    warned_before = mujoco_warning_count()
    model = load_model(xml)
    compiler_warned = mujoco_warning_count() > warned_before
    if model.nu == 0:
        raise MiktError(f"{xml}: the model has no actuator (nothing for a policy to drive)")
    try:
        root = find_root(model, torso)
    except MiktError as err:
        raise MiktError(f"{xml}: {err}") from err
    referenced = model_files(xml)
    # A file the XML names by an absolute path would still be read from there by the copy: such a model, like
    # one loading files from outside its folder, is used in place rather than copied.
    absolute = absolute_references(xml)
    outside = [p for p in referenced if _relative(p, xml.parent) is None]
    copied = not absolute and not outside
    why = (f"it names {absolute[0]} by an absolute path" if absolute
           else f"it loads {outside[0]}, outside its folder" if outside else "")

    staging = folder / f".{name}.{os.getpid()}.tmp"
    try:
        if copied:
            staging.mkdir(parents=True)
            shutil.copy2(xml, staging / xml.name)
            files = []
            for path in referenced:
                relative = _relative(path, xml.parent)
                (staging / relative).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(path, staging / relative)
                files.append(str(relative))
            xml_field, built_from = f"{name}/{xml.name}", (staging / xml.name).resolve()
        else:
            files, xml_field, built_from = [], str(xml.resolve()), xml.resolve()
        chosen, notes = model_choices(model, root)
        if compiler_warned:
            notes.insert(0, Note("warning", f"MuJoCo: {' '.join(last_mujoco_warning().split())}", "xml"))
        edited = edited_model(built_from, chosen.get("floor", False), chosen.get("remove", []))
        try:
            edited_root = find_root(edited, torso or body_name(model, root.body))
        except MiktError as err:
            raise MiktError(f"{xml}: {err}") from err
        chosen |= reset_terms(edited, edited_root, chosen.get("keyframe"))
        env = MjcfEnv(_spec(name, str(built_from), root, model, torso, obs_dim=1, act_dim=model.nu, **chosen))
        check_simulates(env, xml)  # what every later command does first: reset and step
        obs_dim, act_dim = env_dims(env)
        survival, more = survival_choice(env)
        env.close()
        chosen |= survival
        notes += more
        env = MjcfEnv(_spec(name, str(built_from), root, model, torso, obs_dim=obs_dim, act_dim=act_dim, **chosen))
        probes = [probe(env, "zero"), probe(env, "random", RANDOM_PROBE_EPISODES)]
        facts = model_facts(env)
        root_words = env.root.describe(env.model)
        env.close()
        spec = _spec(name, xml_field, root, model, torso, obs_dim=obs_dim, act_dim=act_dim,
                     notes=f"added with `mikt envs add` from {xml.name}", **chosen)
        notes += probe_notes(probes, spec)
        folder.mkdir(parents=True, exist_ok=True)
        # Two `envs add --name X` at once: each step below refuses to replace what the other made, so one wins
        # and the other gets "exists already", and neither removes the winner's files.
        if copied:
            try:
                target_dir.mkdir()
            except FileExistsError:
                raise MiktError(f"{target_dir} exists already", hint="choose another --name") from None
            staging.rename(target_dir)  # onto the empty folder this process just made
        try:
            write_bytes_atomic(target_toml, spec_toml(spec).encode(), exclusive=True)
        except FileExistsError:
            if copied:
                shutil.rmtree(target_dir, ignore_errors=True)
            raise MiktError(f"environment '{name}' exists already: {target_toml} appeared meanwhile",
                            hint="choose another --name") from None
        try:
            spec = load_spec_file(target_toml)  # what every later command reads: it must parse back
        except BaseException:
            target_toml.unlink(missing_ok=True)
            if copied:
                shutil.rmtree(target_dir, ignore_errors=True)
            raise
    except OSError as err:
        raise MiktError(f"cannot write the spec for '{name}' into {folder}: {err.strerror or err}") from err
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
    return AddedEnv(spec, target_toml, spec.xml_path(), copied, files, root_words, facts, why, notes, probes)


def _spec(name: str, xml: str, root: Root, model: mujoco.MjModel, torso: str | None, **fields) -> MjcfSpec:
    return MjcfSpec(name=name, family="mjcf", xml=xml, torso=torso or body_name(model, root.body), **fields)
