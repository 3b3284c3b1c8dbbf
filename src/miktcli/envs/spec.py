"""Environment specs: one TOML file per environment, validated by pydantic.

Specs are looked up in your folder ($MIKT_ENVSPECS, else ./envspecs) and then in the ones shipped with mikt; a
spec of yours with a shipped name wins."""

from __future__ import annotations

import os
import re
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    TypeAdapter,
    ValidationError,
    field_validator,
    model_validator,
)

from miktcli import limits
from miktcli.errors import MiktError, describe_validation_error
from miktcli.limits import read_file_bounded

SPEC_NAME_RE = re.compile(r"^[a-z0-9][a-z0-9._-]{0,63}$")
GYM_ID_RE = re.compile(r"^[A-Za-z0-9_./-]+-v\d+$")
MAX_LEGS = 40  # NerveNet's largest centipede; the model builder nests one body per torso


class _SpecBase(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(description="the name users type; equals the file's stem")
    obs_dim: int = Field(gt=0, description="expected observation dimension, checked when the env is built")
    act_dim: int = Field(gt=0, description="expected action dimension, checked when the env is built")
    max_episode_steps: int = Field(1000, gt=0, le=limits.MAX_EPISODE_STEPS,
                                   description="time limit; reaching it truncates, never terminates")
    notes: str = ""


class CentipedeSpec(_SpecBase):
    """A NerveNet centipede generated from its leg count (see envs/centipede_model.py)."""

    family: Literal["centipede"]
    legs: int = Field(ge=4, le=MAX_LEGS, description="number of legs, even; legs/2 torsos")
    crippled_legs: list[int] = Field(default_factory=list, description="legs whose motors are removed")
    contact_readings: Literal["live", "zero"] = Field(
        "live", description="live: the clipped external contact forces (cfrc_ext after mj_rnePostConstraint), in "
        "the observation and the contact cost, as NerveNet defines them. zero: those entries read 0 and the "
        "contact cost is 0, which is what mujoco-py 2.x gave without mj_rnePostConstraint (CAT's published "
        "two-teacher runs); the observation keeps its size")

    @model_validator(mode="after")
    def _check_legs(self) -> CentipedeSpec:
        if self.legs % 2:
            raise ValueError(f"legs must be even, got {self.legs}")
        bad = [k for k in self.crippled_legs if not 0 <= k < self.legs]
        if bad:
            raise ValueError(f"crippled_legs {bad} out of range 0..{self.legs - 1}")
        if len(set(self.crippled_legs)) != len(self.crippled_legs):
            raise ValueError("crippled_legs has duplicates")
        return self


class GymnasiumSpec(_SpecBase):
    """An environment that gymnasium already ships, made with `gymnasium.make(id, **kwargs)`."""

    family: Literal["gymnasium"]
    id: str = Field(description="a registered gymnasium id such as Ant-v4")
    kwargs: dict[str, Any] = Field(default_factory=dict)

    @field_validator("id")
    @classmethod
    def _registered_id_only(cls, value: str) -> str:
        # gymnasium imports `module` for an id `module:Env`: a spec file must never make it run code.
        if ":" in value:
            raise ValueError(f"'{value}': 'module:Env' ids are refused (they make gymnasium import code)")
        if not GYM_ID_RE.fullmatch(value):
            raise ValueError(f"'{value}': expected a registered gymnasium id such as Ant-v4")
        return value



class MjcfSpec(_SpecBase):
    """A legged body from any MJCF file, with the locomotion task of gymnasium's Hopper, Walker2d and Ant.

    Every term has a default (gymnasium's Hopper-v5 / Walker2d-v5 where those envs agree) and the whole spec,
    defaults included, is copied into each card. See envs/mjcf.py for how each term is computed."""

    family: Literal["mjcf"]
    xml: str = Field(description="the MJCF file, relative to the spec file (or absolute)")
    torso: str | None = Field(None, description="body whose root joint moves the robot (default: the body of the "
                              "free joint, else of the first slide joints)")
    forward_axis: tuple[float, float, float] = Field((1.0, 0.0, 0.0), description="world direction of travel")
    frame_skip: int = Field(4, ge=1, le=1000, description="MuJoCo steps per env step")
    forward_reward_weight: float = 1.0
    ctrl_cost_weight: float = Field(1e-3, ge=0, description="times the sum of squared raw actions")
    contact_cost_weight: float = Field(0.0, ge=0, description="times the sum of squared clipped contact forces")
    healthy_reward: float = Field(1.0, description="bonus for each step that ends healthy")
    terminate_when_unhealthy: bool = True
    healthy_z_min: float | None = Field(None, description="the root's height must stay above (strictly)")
    healthy_z_max: float | None = Field(None, description="... and below (strictly); none: no bound")
    healthy_angle_range: tuple[float, float] | None = Field(
        None, description="open range of the root's hinge angle (planar walkers: its pitch, rad)")
    healthy_state_range: tuple[float, float] | None = Field(
        None, description="open range of every qpos and qvel entry but the root's position (Hopper's check)")
    reset_noise_scale: float = Field(5e-3, ge=0, description="qpos and qvel start at their reference + U(-s, s)")
    qvel_clip: float | None = Field(10.0, gt=0, description="observed velocities are clipped to ±this; none: "
                                    "unclipped")
    contact_forces: bool = Field(False, description="append clipped cfrc_ext of every body but the world")
    contact_force_range: tuple[float, float] = (-1.0, 1.0)
    keyframe: str | None = Field(None, description="reset to this keyframe of the model (its qpos and qvel), plus "
                                 "the reset noise; none: the model's default pose (qpos0)")
    action_map: Literal["raw", "ctrlrange"] = Field(
        "raw", description="raw: the action is the actuators' ctrl as it is (MuJoCo clamps it to ctrlrange); "
        "ctrlrange: an action in [-1, 1] spans each actuator's ctrlrange, 0 at its centre (a position "
        "actuator's centre is the reset pose, so a zero action holds it)")
    floor: bool = Field(False, description="add a ground plane at z = 0 (for a model that has none)")
    remove: list[str] = Field(default_factory=list, description="bodies or world geoms deleted from the model "
                              "before it is compiled (a ball, walls, a height field)")
    _folder: Path | None = PrivateAttr(default=None)  # the spec file's folder, which `xml` is relative to

    @model_validator(mode="after")
    def _check_terms(self) -> MjcfSpec:
        if not any(self.forward_axis):
            raise ValueError("forward_axis must not be zero")
        for field in ("healthy_angle_range", "healthy_state_range", "contact_force_range"):
            pair = getattr(self, field)
            if pair is not None and not pair[0] < pair[1]:
                raise ValueError(f"{field} {list(pair)} is empty (low must be below high)")
        if None not in (self.healthy_z_min, self.healthy_z_max) and not self.healthy_z_min < self.healthy_z_max:
            raise ValueError(f"healthy_z_min {self.healthy_z_min} must be below healthy_z_max {self.healthy_z_max}")
        if len(set(self.remove)) != len(self.remove):
            raise ValueError(f"remove {self.remove} names a body or geom twice")
        return self

    def located(self, folder: Path) -> MjcfSpec:
        self._folder = Path(folder)
        return self

    def xml_path(self) -> Path:
        path = Path(self.xml).expanduser()
        if path.is_absolute():
            return path
        if self._folder is None:
            raise MiktError(f"environment '{self.name}': its xml '{self.xml}' is relative, but the spec was not "
                            "read from a file")
        return self._folder / path


AnySpec = CentipedeSpec | GymnasiumSpec | MjcfSpec

# Fields added to a spec family after runs had recorded specs (and their fingerprints) without them: at their
# default they are left out of a spec's record, so that an older run's spec still reads as the same task.
LATER_DEFAULTS: dict[type[AnySpec], dict[str, Any]] = {
    MjcfSpec: {"keyframe": None, "action_map": "raw", "floor": False, "remove": []},
    CentipedeSpec: {"contact_readings": "live"},
}
EnvSpec = Annotated[AnySpec, Field(discriminator="family")]
_spec_adapter: TypeAdapter[AnySpec] = TypeAdapter(EnvSpec)


def parse_spec(data: dict[str, Any]) -> AnySpec:
    """Validate a spec given as a dict (e.g. the copy stored in a teacher card)."""
    return _spec_adapter.validate_python(data)


def shipped_specs_dir() -> Path:
    """The specs that ship with mikt: the checkout's envspecs/, else the copy in the wheel."""
    here = Path(__file__).resolve()
    checkout = here.parents[3] / "envspecs"
    if checkout.is_dir():
        return checkout
    return here.parents[1] / "_envspecs"


def user_specs_dir() -> Path:
    """Where your own specs live and `mikt envs add` writes: $MIKT_ENVSPECS, else ./envspecs (it need not
    exist yet)."""
    override = os.environ.get("MIKT_ENVSPECS")
    if override:
        if not Path(override).is_dir():  # else every listing is silently empty
            raise MiktError(f"MIKT_ENVSPECS={override} is not a folder",
                            hint="point it at a folder of *.toml specs, or unset it")
        return Path(override)
    return Path("envspecs")


def spec_dirs() -> list[Path]:
    """The folders specs are looked up in, first wins: your specs, then the shipped ones (one folder when they
    are the same, as in a checkout run from its root)."""
    dirs = [user_specs_dir(), shipped_specs_dir()]
    if not dirs[0].is_dir() or dirs[0].resolve() == dirs[1].resolve():
        dirs = dirs[1:]
    return dirs


def envspecs_dir() -> Path:
    """The first folder specs are looked up in (see `spec_dirs`)."""
    return spec_dirs()[0]


def load_spec_file(path: Path) -> AnySpec:
    try:
        if path.is_dir():  # a folder named x.toml: not a spec, and never a reason to hide the others
            raise MiktError(f"{path}: a folder, not a spec file")
        data = tomllib.loads(read_file_bounded(path, str(path), limits.MAX_JSON_BYTES).decode("utf-8"))
    except OSError as err:  # unreadable (permissions), vanished since the listing
        raise MiktError(f"{path}: cannot be read: {err.strerror or err}") from err
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise MiktError(f"{path}: not valid TOML: {err}") from err
    except RecursionError:  # tomllib recurses once per level of nesting
        raise MiktError(f"{path}: not valid TOML: nested too deeply") from None
    try:
        spec = parse_spec(data)
    except ValidationError as err:
        raise MiktError(f"{path}: {describe_validation_error(err)}") from err
    if spec.name != path.stem:
        raise MiktError(f"{path}: field 'name': '{spec.name}' must equal the file name '{path.stem}'")
    if isinstance(spec, MjcfSpec):
        spec.located(path.parent)
    return spec


def _folders(directory: Path | None) -> list[Path]:
    return [directory] if directory is not None else spec_dirs()


def _spec_files(directory: Path | None) -> dict[str, Path]:
    """name → spec file, the first folder of `spec_dirs` winning (or only `directory` when given). A folder
    named x.toml is not a spec: it neither counts as one nor hides a shipped x.toml (see `_stray_folders`)."""
    files: dict[str, Path] = {}
    for folder in _folders(directory):
        for path in sorted(folder.glob("*.toml")):
            if path.is_file():
                files.setdefault(path.stem, path)
    return dict(sorted(files.items()))


def _stray_folders(directory: Path | None) -> list[Path]:
    """Folders named *.toml among the spec folders: named by `scan_specs` so the user can tell why."""
    return [path for folder in _folders(directory) for path in sorted(folder.glob("*.toml")) if path.is_dir()]


def _searched(directory: Path | None) -> str:
    """The spec folders a lookup read, each said with how it was chosen, for a name it did not find."""
    if directory is not None:
        return str(Path(directory).resolve())
    mine = user_specs_dir()
    how = "$MIKT_ENVSPECS" if os.environ.get("MIKT_ENVSPECS") else "./envspecs, as MIKT_ENVSPECS is unset"
    missing = "" if mine.is_dir() else "; no such folder"
    shipped = shipped_specs_dir()
    if mine.is_dir() and mine.resolve() == shipped.resolve():
        return f"{shipped.resolve()} (the shipped specs, also {how})"
    return f"{mine.resolve()} ({how}{missing}), then the shipped specs"


def spec_names(directory: Path | None = None) -> list[str]:
    return list(_spec_files(directory))


def load_spec(name: str, directory: Path | None = None) -> AnySpec:
    if not SPEC_NAME_RE.fullmatch(name):
        raise MiktError(f"invalid environment name '{name}': lowercase letters, digits, '.', '_' and '-'")
    files = _spec_files(directory)
    if name not in files:
        known = ", ".join(files) or "(none)"
        raise MiktError(f"unknown environment '{name}'; known: {known} (looked in {_searched(directory)})",
                        hint="add it with `mikt envs add FILE.xml --name NAME`, or run from the folder that holds "
                        "your envspecs/ (or set MIKT_ENVSPECS)")
    return load_spec_file(files[name])


def load_all_specs(directory: Path | None = None) -> list[AnySpec]:
    """Every valid spec; raises on the first bad one (see `scan_specs` to list good and bad together)."""
    good, bad = scan_specs(directory)
    if bad:
        raise bad[0]
    return good


def scan_specs(directory: Path | None = None) -> tuple[list[AnySpec], list[MiktError]]:
    """The valid specs, and one error per file that is not (a bad file never hides the good ones)."""
    good, bad = [], []
    for path in [*_spec_files(directory).values(), *_stray_folders(directory)]:
        try:
            good.append(load_spec_file(path))
        except MiktError as err:
            bad.append(err)
    return good, bad
