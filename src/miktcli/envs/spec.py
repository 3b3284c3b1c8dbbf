"""Environment specs: one TOML file per environment, validated by pydantic."""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError, model_validator

from miktcli.errors import MiktError


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
    legs: int = Field(ge=4, description="number of legs, even; legs/2 torsos")
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


class GymnasiumSpec(_SpecBase):
    """An environment that gymnasium already ships, made with `gymnasium.make(id, **kwargs)`."""

    family: Literal["gymnasium"]
    id: str
    kwargs: dict[str, Any] = Field(default_factory=dict)


EnvSpec = Annotated[CentipedeSpec | GymnasiumSpec, Field(discriminator="family")]
_spec_adapter: TypeAdapter[CentipedeSpec | GymnasiumSpec] = TypeAdapter(EnvSpec)


def parse_spec(data: dict[str, Any]) -> CentipedeSpec | GymnasiumSpec:
    """Validate a spec given as a dict (e.g. the copy stored in a teacher card)."""
    return _spec_adapter.validate_python(data)


def envspecs_dir() -> Path:
    """Where spec files live: $MIKT_ENVSPECS, else the checkout's envspecs/, else the copy in the wheel."""
    override = os.environ.get("MIKT_ENVSPECS")
    if override:
        return Path(override)
    here = Path(__file__).resolve()
    checkout = here.parents[3] / "envspecs"
    if checkout.is_dir():
        return checkout
    return here.parents[1] / "_envspecs"


def _describe_validation_error(path: Path, err: ValidationError) -> str:
    first = err.errors()[0]
    loc = ".".join(str(p) for p in first["loc"] if p not in ("centipede", "gymnasium")) or "(file)"
    if first["type"] == "union_tag_invalid":
        return f"{path}: field 'family': unknown family, expected 'centipede' or 'gymnasium'"
    if first["type"] == "union_tag_not_found":
        return f"{path}: field 'family': missing"
    return f"{path}: field '{loc}': {first['msg']}"


def load_spec_file(path: Path) -> CentipedeSpec | GymnasiumSpec:
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise MiktError(f"{path}: not valid TOML: {err}") from err
    try:
        spec = parse_spec(data)
    except ValidationError as err:
        raise MiktError(_describe_validation_error(path, err)) from err
    if spec.name != path.stem:
        raise MiktError(f"{path}: field 'name': '{spec.name}' must equal the file name '{path.stem}'")
    return spec


def spec_names(directory: Path | None = None) -> list[str]:
    directory = directory or envspecs_dir()
    return sorted(p.stem for p in directory.glob("*.toml"))


def load_spec(name: str, directory: Path | None = None) -> CentipedeSpec | GymnasiumSpec:
    directory = directory or envspecs_dir()
    path = directory / f"{name}.toml"
    if not path.is_file():
        known = ", ".join(spec_names(directory)) or "(none)"
        raise MiktError(f"unknown environment '{name}'; known: {known}")
    return load_spec_file(path)


def load_all_specs(directory: Path | None = None) -> list[CentipedeSpec | GymnasiumSpec]:
    directory = directory or envspecs_dir()
    return [load_spec_file(p) for p in sorted(directory.glob("*.toml"))]
