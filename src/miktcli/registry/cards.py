"""The pydantic cards: the single definition of what a teacher file and a run record hold."""

from __future__ import annotations

import datetime as dt
import functools
import importlib.metadata
import subprocess
from pathlib import Path
from typing import Any, Literal, NamedTuple

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from miktcli import compat
from miktcli.engine.ppo import PPOConfig

# A card is written with the newest version this code knows; a reader refuses a newer one with a message
# instead of a validation error about a field it has never heard of. Every version reads every older one.
# Teacher: 2 adds `code_history`, 3 `obs_clip`, 4 `method` and `trained_with`, 5 `env_fingerprint` and
# `env_files` (the environment the file carries, registry/carried.py). Run: 2 adds the status
# `created` and `code_history`, 3 `config.eval_episodes`, 4 `branched_from`, `env_spec`, `env_fingerprint`
# and `config.ppo.flush_denormal`.
TEACHER_SCHEMA_VERSION = 5
RUN_SCHEMA_VERSION = 4


class TeacherVersion(NamedTuple):
    """One version of a teacher, written `name@vN` wherever mikt names it (what `eval`, `transfer` and the
    registry resolve)."""

    name: str
    version: int

    def __str__(self) -> str:
        return f"{self.name}@v{self.version}"


def now() -> dt.datetime:
    return dt.datetime.now(dt.UTC).replace(microsecond=0)


def package_versions() -> dict[str, str]:
    """The versions of the packages this process runs (a copy: callers keep it in cards)."""
    return dict(_package_versions())


@functools.cache
def _package_versions() -> dict[str, str]:
    # Read once per process, as code_version: the packages a process runs are those it imported at the start,
    # and reading their metadata (~10 ms each time) was most of the cost of preparing a large study's cells.
    versions = {}
    for pkg in ("mikt", "torch", "gymnasium", "mujoco", "numpy", "safetensors"):
        try:
            versions[pkg] = importlib.metadata.version(pkg)
        except importlib.metadata.PackageNotFoundError:
            versions[pkg] = "unknown"
    return versions


@functools.cache
def code_version() -> str:
    """The git commit of the checkout that runs (with '+dirty' for local edits), else the package version.

    Read once per process: the code a process runs is what it imported at the start, whatever the checkout
    turns into while it trains."""
    root = Path(__file__).resolve().parents[2]
    try:
        commit = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True, text=True, timeout=5
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no", "src"],
            capture_output=True, text=True, timeout=5,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit, dirty = "", ""
    if not commit:
        return f"mikt {package_versions()['mikt']}"
    return commit + ("+dirty" if dirty else "")


class CodeSegment(BaseModel):
    """The code that trained a run from `from_step` on, until the next segment. A run continued under another
    commit or other package versions (resumed after an upgrade, a study restarted at a newer commit) gets a
    new segment; resuming under the same code does not."""

    model_config = ConfigDict(extra="forbid")

    from_step: int = Field(ge=0)
    code_version: str
    packages: dict[str, str]
    started: dt.datetime


def describe_code_history(history: list[CodeSegment], created_with: str, trained: bool = True) -> str:
    """One line: which commit trained which steps. Cards written before mikt recorded the history (or steps
    trained before its first segment) say so rather than guess; `trained` False: nothing has trained yet."""
    if not history and not trained:
        return "not trained yet"
    parts = [] if history and history[0].from_step == 0 else [f"not recorded (run created with {created_with})"]
    parts += [f"{s.code_version} from step {s.from_step:,}" for s in history]
    return "; ".join(parts)


class TeacherCard(BaseModel):
    """Stored as JSON in the teacher's safetensors metadata."""

    model_config = ConfigDict(extra="forbid")

    schema_version: int = TEACHER_SCHEMA_VERSION
    name: str
    version: int = Field(ge=1)
    env: str
    env_spec: dict[str, Any]
    # the spec's and its model files' sha256 (envs/fingerprint.py) when it was trained; None on older cards
    env_fingerprint: str | None = None
    # the spec and model files the file carries as uint8 tensors `env/PATH` (registry/carried.py), the spec
    # first; empty: it carries none (older cards, run students, a model too large or outside its folder)
    env_files: list[str] = Field(default_factory=list)
    # sha256 of those carried tensors, checked whenever the file is read (used or not, a tampered byte in the
    # file is refused, as it is in the policy's tensors); None when it carries none
    env_files_sha256: str | None = None
    obs_dim: int = Field(gt=0)
    act_dim: int = Field(gt=0)
    pi_hidden: list[int]
    vf_hidden: list[int]
    activation: Literal["tanh", "relu"] = "tanh"  # hidden layers; mikt trains tanh, imported teachers may be relu
    # The normaliser's clip of normalised observations; None: not clipped (a teacher imported without
    # statistics saw raw observations). Cards before this field were all clipped at ±10.
    obs_clip: float | None = Field(10.0, gt=0)
    # How actions reached the env in training, and so how to evaluate the policy.
    clip_actions_for_env: bool
    steps: int
    seed: int | None  # None: unknown (an imported teacher)
    final_return: float | None
    best_return: float | None
    hyperparameters: dict[str, Any]
    packages: dict[str, str]
    code_version: str
    # which code trained the source run's steps; empty for imported teachers and older cards
    code_history: list[CodeSegment] = Field(default_factory=list)
    source_run: str | None = None
    imported_from: dict[str, Any] | None = None  # a teacher trained elsewhere: format, file and its sha256
    # a transfer run's student added as a teacher (`mikt teacher add`): the method and teachers it learned with
    method: str | None = None
    trained_with: list[str] = Field(default_factory=list)
    created: dt.datetime
    tensors_sha256: str

    @model_validator(mode="before")
    @classmethod
    def _older(cls, data: Any) -> Any:
        return compat.teacher_card(data)

    @property
    def ref(self) -> str:
        return str(TeacherVersion(self.name, self.version))


class TeacherRef(BaseModel):
    """A run card's record of one of its teachers: which version, and the tensors it had."""

    model_config = ConfigDict(extra="forbid")

    name: str
    version: int
    sha256: str
    obs_dim: int
    env: str

    @property
    def ref(self) -> str:
        return str(TeacherVersion(self.name, self.version))


class RunConfig(BaseModel):
    """What a run trains: the engine's settings, the student's layer sizes and the method's own options."""

    model_config = ConfigDict(extra="forbid")

    ppo: PPOConfig
    pi_hidden: list[int]
    vf_hidden: list[int]
    options: dict[str, Any] | None = Field(None, description="the method's options, validated by its options model")
    teacher_name: str | None = Field(None, description="teacher runs: the name the teacher is published as")
    eval_episodes: int | None = Field(None, ge=1, description="transfer runs: episodes of the final evaluation "
                                      "(None on cards before schema 3: the resuming command's decides)")

    @field_validator("ppo", mode="before")
    @classmethod
    def _ppo_record(cls, value: Any) -> Any:
        return PPOConfig.from_record(value) if isinstance(value, dict) else value

    @model_validator(mode="before")
    @classmethod
    def _older(cls, data: Any) -> Any:
        return compat.run_config(data)


class BranchPoint(BaseModel):
    """Where a branched run started: another run's kept checkpoint (see workflows/branch.py)."""

    model_config = ConfigDict(extra="forbid")

    run: str
    checkpoint: str
    step: int = Field(ge=0)


# `created`: the folder exists and nothing has trained yet (a study's prepared cell); training sets `running`.
RunStatus = Literal["created", "running", "completed", "interrupted", "failed"]


class RunCard(BaseModel):
    """run.json of a run folder; checkpoints carry a copy in their metadata."""

    model_config = ConfigDict(extra="forbid")

    schema_version: int = RUN_SCHEMA_VERSION
    run_id: str
    kind: Literal["teacher", "transfer"]
    status: RunStatus
    env: str
    method: str
    teachers: list[TeacherRef] = Field(default_factory=list)
    seed: int
    total_steps: int
    steps_done: int = 0
    config: RunConfig
    command: str
    created: dt.datetime
    updated: dt.datetime
    code_version: str  # the code that created the run; code_history says what trained it
    packages: dict[str, str]
    code_history: list[CodeSegment] = Field(default_factory=list)
    result: dict[str, Any] = Field(default_factory=dict)
    error: str | None = None
    branched_from: BranchPoint | None = None
    seeds_together: list[str] = Field(
        default_factory=list, description="the runs (this one among them) that trained in one process as one "
        "batched problem (miktcli.engine.together): the same distribution as training alone, not the same bits; "
        "empty: trained alone")
    # the environment as the run started on it (envs/fingerprint.py); None on cards before schema 4
    env_spec: dict[str, Any] | None = None
    env_fingerprint: str | None = None
