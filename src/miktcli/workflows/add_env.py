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
from dataclasses import dataclass
from pathlib import Path

import mujoco

from miktcli.envs.factory import env_dims, model_facts
from miktcli.envs.mjcf import MjcfEnv, Root, absolute_references, body_name, find_root, load_model, model_files
from miktcli.envs.spec import SPEC_NAME_RE, MjcfSpec, load_spec_file, spec_names, user_specs_dir
from miktcli.errors import MiktError
from miktcli.registry.files import write_bytes_atomic

# healthy_z_min of an added model: this fraction of the torso's starting height (gymnasium's Hopper, Walker2d
# and Humanoid stop at 0.56, 0.64 and 0.71 of theirs); no other health check, nothing else but defaults.
HEALTHY_HEIGHT_FRACTION = 0.5


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


def default_terms(model: mujoco.MjModel, root: Root) -> dict:
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    height = float(data.xpos[root.body][2])
    return {"healthy_z_min": round(HEALTHY_HEIGHT_FRACTION * height, 3)} if height > 0 else {}


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
    model = load_model(xml)
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
        env = MjcfEnv(_spec(name, str(built_from), root, model, torso, obs_dim=1, act_dim=model.nu))
        check_simulates(env, xml)  # what every later command does first: reset and step
        obs_dim, act_dim = env_dims(env)
        facts = model_facts(env)
        root_words = env.root.describe(env.model)
        env.close()
        spec = _spec(name, xml_field, root, model, torso, obs_dim=obs_dim, act_dim=act_dim,
                     notes=f"added with `mikt envs add` from {xml.name}")
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
    return AddedEnv(spec, target_toml, spec.xml_path(), copied, files, root_words, facts, why)


def _spec(name: str, xml: str, root: Root, model: mujoco.MjModel, torso: str | None, **fields) -> MjcfSpec:
    return MjcfSpec(name=name, family="mjcf", xml=xml, torso=torso or body_name(model, root.body),
                    **default_terms(model, root), **fields)
