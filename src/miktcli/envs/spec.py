"""Environment specs: one TOML file per environment, validated by pydantic."""

from __future__ import annotations

import os
import re
import tomllib
import warnings
from pathlib import Path
from typing import Annotated, Any, Literal

import gymnasium as gym
from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError, field_validator, model_validator

from miktcli import limits
from miktcli.envs.centipede import CentipedeEnv
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
    max_episode_steps: int = Field(1000, gt=0, description="time limit; reaching it truncates, never terminates")
    notes: str = ""


class CentipedeSpec(_SpecBase):
    """A NerveNet centipede generated from its leg count (see envs/centipede_model.py)."""

    family: Literal["centipede"]
    legs: int = Field(ge=4, le=MAX_LEGS, description="number of legs, even; legs/2 torsos")
    crippled_legs: list[int] = Field(default_factory=list, description="legs whose motors are removed")

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

    def build(self, render_mode: str | None = None) -> gym.Env:
        return CentipedeEnv(self.legs, self.crippled_legs, max_episode_steps=self.max_episode_steps,
                            render_mode=render_mode)


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

    def build(self, render_mode: str | None = None) -> gym.Env:
        with warnings.catch_warnings():
            # Ant-v4 with contact forces is deprecated upstream but is exactly the paper's Ant-v2 layout (111 dims).
            warnings.filterwarnings("ignore", message=".*is out of date.*")
            warnings.filterwarnings("ignore", category=DeprecationWarning)
            try:
                return gym.make(self.id, max_episode_steps=self.max_episode_steps, render_mode=render_mode,
                                disable_env_checker=True, **self.kwargs)
            except gym.error.Error as err:
                raise MiktError(f"environment '{self.name}': gymnasium cannot make '{self.id}': {err}") from err
            except Exception as err:  # noqa: BLE001 - kwargs reach the env's own constructor, which may fail anyhow
                raise MiktError(f"environment '{self.name}': '{self.id}' fails with these kwargs: "
                                f"{type(err).__name__}: {err}") from err


EnvSpec = Annotated[CentipedeSpec | GymnasiumSpec, Field(discriminator="family")]
_spec_adapter: TypeAdapter[CentipedeSpec | GymnasiumSpec] = TypeAdapter(EnvSpec)


def parse_spec(data: dict[str, Any]) -> CentipedeSpec | GymnasiumSpec:
    """Validate a spec given as a dict (e.g. the copy stored in a teacher card)."""
    return _spec_adapter.validate_python(data)


def envspecs_dir() -> Path:
    """Where spec files live: $MIKT_ENVSPECS, else the checkout's envspecs/, else the copy in the wheel."""
    override = os.environ.get("MIKT_ENVSPECS")
    if override:
        if not Path(override).is_dir():  # else every listing is silently empty
            raise MiktError(f"MIKT_ENVSPECS={override} is not a folder",
                            hint="point it at a folder of *.toml specs, or unset it")
        return Path(override)
    here = Path(__file__).resolve()
    checkout = here.parents[3] / "envspecs"
    if checkout.is_dir():
        return checkout
    return here.parents[1] / "_envspecs"


def load_spec_file(path: Path) -> CentipedeSpec | GymnasiumSpec:
    try:
        if path.is_dir():  # a folder named x.toml: not a spec, and never a reason to hide the others
            raise MiktError(f"{path}: a folder, not a spec file")
        data = tomllib.loads(read_file_bounded(path, str(path), limits.MAX_JSON_BYTES).decode("utf-8"))
    except OSError as err:  # unreadable (permissions), vanished since the listing
        raise MiktError(f"{path}: cannot be read: {err.strerror or err}") from err
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise MiktError(f"{path}: not valid TOML: {err}") from err
    try:
        spec = parse_spec(data)
    except ValidationError as err:
        raise MiktError(f"{path}: {describe_validation_error(err)}") from err
    if spec.name != path.stem:
        raise MiktError(f"{path}: field 'name': '{spec.name}' must equal the file name '{path.stem}'")
    return spec


def spec_names(directory: Path | None = None) -> list[str]:
    directory = directory or envspecs_dir()
    return sorted(p.stem for p in directory.glob("*.toml") if p.is_file())


def load_spec(name: str, directory: Path | None = None) -> CentipedeSpec | GymnasiumSpec:
    directory = directory or envspecs_dir()
    if not SPEC_NAME_RE.fullmatch(name):
        raise MiktError(f"invalid environment name '{name}': lowercase letters, digits, '.', '_' and '-'")
    path = directory / f"{name}.toml"
    if not path.is_file():
        known = ", ".join(spec_names(directory)) or "(none)"
        raise MiktError(f"unknown environment '{name}'; known: {known}")
    return load_spec_file(path)


def load_all_specs(directory: Path | None = None) -> list[CentipedeSpec | GymnasiumSpec]:
    """Every valid spec; raises on the first bad one (see `scan_specs` to list good and bad together)."""
    good, bad = scan_specs(directory)
    if bad:
        raise bad[0]
    return good


def scan_specs(directory: Path | None = None) -> tuple[list[CentipedeSpec | GymnasiumSpec], list[MiktError]]:
    """The valid specs, and one error per file that is not (a bad file never hides the good ones)."""
    directory = directory or envspecs_dir()
    good, bad = [], []
    for path in sorted(directory.glob("*.toml")):
        try:
            good.append(load_spec_file(path))
        except MiktError as err:
            bad.append(err)
    return good, bad
