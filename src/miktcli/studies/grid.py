"""A study grid (TOML): pairs × methods × seeds on one budget, and the key of each cell's run."""

from __future__ import annotations

import tomllib
from collections import Counter
from pathlib import Path
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError, field_validator, model_validator

from miktcli import compat
from miktcli.engine.ppo import PPOConfig
from miktcli.errors import MiktError, describe_validation_error
from miktcli.limits import open_regular
from miktcli.methods import get_method, transfer_methods

# A grid's size limits. Every cell is a run folder and a line of state.json and results.md; beyond these a
# grid is a mistake (a seed range typed wrong), and preparing it would take minutes before any cell trains.
MAX_GRID_CELLS = 10_000  # pairs × methods × seeds
MAX_GRID_FILE_BYTES = 1024 * 1024  # the TOML file; the committed grids are under 2 kB


class PairSpec(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True)

    teachers: list[str] = Field(alias="from", min_length=1)
    to: str
    label: str | None = None
    seeds: list[Annotated[int, Field(ge=0, le=2**32 - 1)]] | None = Field(
        None, min_length=1, description="this pair's seeds for the methods with teachers, in place of the grid's; "
        "runs from scratch are the target's, shared by its pairs, and keep the grid's seeds")

    @property
    def teacher_names(self) -> str:
        """The teachers without their versions, "a+b": as the pair's name and a reference result name them."""
        return "+".join(t.split("@")[0] for t in self.teachers)

    @property
    def name(self) -> str:
        return self.label or f"{self.teacher_names} → {self.to}"


class MethodSpec(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True)

    name: str
    method: str
    kl_coef: float | None = Field(None, ge=0, allow_inf_nan=False)
    # the method's options (`options = { mi = false }`), checked by the method's own options model
    options: dict[str, Any] = Field(default_factory=dict)
    # PPO settings (`ppo = { clip_range = 0.1 }`), checked by PPOConfig: as `--ppo KEY=VALUE`
    ppo: dict[str, Any] = Field(default_factory=dict)

    @model_validator(mode="before")
    @classmethod
    def _older(cls, data: Any) -> Any:
        return compat.grid_method(data)

    @field_validator("method")
    @classmethod
    def _known(cls, value: str) -> str:
        if value not in transfer_methods():
            raise ValueError(f"unknown method '{value}', expected one of {', '.join(transfer_methods())}")
        return value

    @model_validator(mode="after")
    def _valid_options(self) -> MethodSpec:
        # checked when the grid is read, so a bad option of one method creates no run of another
        try:
            get_method(self.method).parse_options(self.options)
            PPOConfig.with_settings(self.ppo, kl_coef=self.kl_coef)
        except MiktError as err:
            raise ValueError(str(err)) from None
        return self

    @property
    def uses_teachers(self) -> bool:
        return not get_method(self.method).trains_from_scratch


class ReportRequest(BaseModel):
    """A report section the grid asks for beyond the standard ones (`[[report]]`, section = NAME, then the
    section's own options, checked by the section when the study is opened: studies.sections)."""

    model_config = ConfigDict(extra="allow")

    section: str

    @property
    def options(self) -> dict[str, Any]:
        return dict(self.model_extra or {})


def file_slug(text: str) -> str:
    """A pair's or method's name as a file or folder name (plots, TensorBoard runs)."""
    return "".join(c if c.isalnum() or c in "._-" else "-" for c in text.replace(" → ", "-to-")).strip("-")


class Grid(BaseModel):
    model_config = ConfigDict(extra="forbid")

    # the default results folder is ./studies/NAME: a name, never a path
    name: str = Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")
    steps: int = Field(gt=0)
    seeds: list[Annotated[int, Field(ge=0, le=2**32 - 1)]] = Field(min_length=1)
    marks: list[int] = Field(default_factory=list, description="step marks of the results table")
    eval_episodes: int = Field(10, ge=1)
    baseline: str = Field("vpg", description="the method whose final return the others race to")
    random_returns: bool = Field(True, description="the report's across-pairs section, normalised between the "
                                 "random policy (measured once per target into the study folder) and the baseline")
    compile_loss: bool = Field(False, description="every cell's PPO loss through torch.compile (see --compile)")
    seeds_together: bool = Field(False, description="train each cell's seeds in one process as one batched "
                                 "problem (mikt transfer --seeds): the same distribution, not the same bits; "
                                 "on Ray (--workers, --address) a cell's seeds are one task")
    pairs: list[PairSpec] = Field(min_length=1)
    methods: list[MethodSpec] = Field(min_length=1)
    report: list[ReportRequest] = Field(default_factory=list, description="sections after the standard ones")
    # the grid file's folder: a section's file option (a reference result) is read relative to it
    _folder: Path | None = PrivateAttr(None)

    def seeds_of(self, pair: PairSpec, method: MethodSpec) -> list[int]:
        """The seeds a pair's method trains: the pair's own for a method with teachers, else the grid's."""
        return pair.seeds if pair.seeds is not None and method.uses_teachers else self.seeds

    @property
    def baseline_trains_from_scratch(self) -> bool:
        """Whether the baseline has no teachers: then its runs are shared by every pair of a target."""
        return not next(m for m in self.methods if m.name == self.baseline).uses_teachers

    @property
    def folder(self) -> Path:
        return self._folder or Path.cwd()

    @model_validator(mode="after")
    def _no_duplicates(self) -> Grid:
        cells = sum(len(p.seeds or self.seeds) for p in self.pairs) * len(self.methods)
        if cells > MAX_GRID_CELLS:
            seeds = (f"{len(self.seeds):,} seed(s)" if all(p.seeds is None for p in self.pairs)
                     else "each pair's seeds")
            raise ValueError(f"{cells:,} cells ({len(self.pairs):,} pair(s) × {len(self.methods):,} method(s) × "
                             f"{seeds}); a grid holds at most {MAX_GRID_CELLS:,}")
        # Two methods of one name would share cells and overwrite each other; so would two equal pairs.
        # Report files are named by slugs, so names that differ only in punctuation would overwrite each other.
        for what, keys in (("method name", [m.name for m in self.methods]),
                           ("method name (as a file name)", [file_slug(m.name) for m in self.methods]),
                           ("pair", [f"{'+'.join(p.teachers)} → {p.to}" for p in self.pairs]),
                           ("pair label", [p.name for p in self.pairs]),
                           ("pair label (as a file name)", [file_slug(p.name) for p in self.pairs]),
                           ("seed", [str(s) for s in self.seeds]),
                           *((f"seed of pair {p.name}", [str(s) for s in p.seeds]) for p in self.pairs if p.seeds)):
            dupes = sorted(k for k, n in Counter(keys).items() if n > 1)  # linear: 100,000 seeds took minutes
            if dupes:
                raise ValueError(f"duplicate {what}: {', '.join(dupes)}")
        beyond = [m for m in self.marks if not 0 < m <= self.steps]
        if beyond:
            raise ValueError(f"mark {beyond[0]:,} is outside the run's 1…{self.steps:,} steps")
        if self.baseline not in {m.name for m in self.methods}:
            raise ValueError(f"baseline '{self.baseline}' is not one of the methods")
        return self


def load_grid(path: Path) -> Grid:
    if not Path(path).exists():
        raise MiktError(f"grid file {path} not found")
    try:
        with open_regular(path, str(path)) as f:  # a FIFO or a device is refused, never waited on
            raw = f.read(MAX_GRID_FILE_BYTES + 1)  # never more than the limit, whatever the file
        if len(raw) > MAX_GRID_FILE_BYTES:
            raise MiktError(f"{path}: a grid file holds at most {MAX_GRID_FILE_BYTES:,} bytes; this one is larger")
        data = tomllib.loads(raw.decode("utf-8"))
        grid = Grid.model_validate(data)
        grid._folder = Path(path).resolve().parent
        return grid
    except FileNotFoundError:
        raise MiktError(f"grid file {path} not found") from None
    except tomllib.TOMLDecodeError as err:
        raise MiktError(f"{path}: not valid TOML: {err}") from err
    except RecursionError:  # tomllib (and pydantic) recurse once per level of nesting
        raise MiktError(f"{path}: not valid TOML: nested too deeply") from None
    except UnicodeDecodeError:
        raise MiktError(f"{path}: not valid TOML: not a UTF-8 text file") from None
    except ValidationError as err:
        raise MiktError(f"{path}: {describe_validation_error(err)}") from err


def cell_key(pair: PairSpec, method: MethodSpec, seed: int) -> str:
    """The run a cell needs. A method without teachers (vpg) is the same run whatever the pair, so every
    pair with that target shares it: the key leaves the teachers out ("-" in their place)."""
    source = "+".join(pair.teachers) if method.uses_teachers else "-"
    return f"{source}>{pair.to}|{method.name}|{seed}"
