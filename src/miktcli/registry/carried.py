"""The environment a run or a teacher trained on travels with it, so that `eval`, `--resume`, `teacher add`
and `--from` work from a folder that has no spec folder of its own (a robot added with `mikt envs add`).

A run folder carries its spec and every file the spec's model loads in `runN/env/`, laid out as a spec folder
(`NAME.toml`, and for an `mjcf` spec its XML, includes and meshes at the same paths relative to it). A teacher
file carries the same files as uint8 tensors `env/PATH`, listed in its card's `env_files`: a teacher stays one
file, in a registry or packaged in a wheel, and nothing is ever written beside it (a teacher's copy is written
to a temporary folder of the process that uses it). Every copy is checked against the fingerprint its card
records (envs/fingerprint.py) each time it is used, so a tampered copy is refused in one line.

The lookup order for the environment of an existing run or teacher:

1. the spec folders (`$MIKT_ENVSPECS` or ./envspecs, then the shipped specs): a spec found there is used, and
   refused, as ever, when it differs from the one recorded; a carried copy never hides an edit;
2. else the copy the run or teacher carries, refused when it does not match the recorded fingerprint;
3. else the environment is unknown, in one line that says where it was looked for.

A new run's target is looked up the same way, step 2 being the copy one of its teachers carries.

Not carried (the run or teacher then needs its spec in a spec folder, as before): a spec that names its XML by
an absolute path, a model that loads a file outside its spec's folder or names one by an absolute path, and a
model whose files pass `limits.MAX_CARRIED_MODEL_BYTES`.
"""

from __future__ import annotations

import atexit
import hashlib
import os
import shutil
import tempfile
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import torch

from miktcli import limits
from miktcli.envs.factory import SpecName
from miktcli.envs.fingerprint import describe_change, spec_fingerprint, spec_record
from miktcli.envs.mjcf import model_files
from miktcli.envs.spec import SPEC_NAME_RE, AnySpec, MjcfSpec, load_spec, load_spec_file, spec_dirs
from miktcli.errors import MiktError
from miktcli.registry.cards import TeacherCard
from miktcli.registry.files import deferred_interrupt

ENV_DIR = "env"  # in a run folder: runN/env/NAME.toml, and the model beside it
TENSOR_PREFIX = "env/"  # in a teacher file: one uint8 tensor per carried file
NO_COPY_HINT = ("point MIKT_ENVSPECS at the folder that holds its spec (`mikt envs add` writes to ./envspecs of "
                "the folder it ran in)")


class NotCarried(Exception):  # noqa: N818 - a reason, not a failure: the run or teacher goes on without a copy
    """Why an environment cannot travel with a run or a teacher."""


@dataclass(frozen=True)
class EnvFiles:
    """A spec file and the files its model loads, by path relative to the spec's folder, the spec first."""

    name: str
    files: dict[str, bytes]

    @property
    def size(self) -> int:
        return sum(len(data) for data in self.files.values())

    def tensors(self) -> dict[str, torch.Tensor]:
        """The files as uint8 tensors `env/PATH`, for a teacher file."""
        return {TENSOR_PREFIX + path: (torch.frombuffer(bytearray(data), dtype=torch.uint8) if data
                                       else torch.zeros(0, dtype=torch.uint8))
                for path, data in self.files.items()}

    @classmethod
    def from_tensors(cls, where: Path, name: str, listed: list[str],
                     tensors: dict[str, torch.Tensor]) -> EnvFiles:
        """The files a teacher file carries: exactly those its card lists, each a safe relative path."""
        found = sorted(k[len(TENSOR_PREFIX):] for k in tensors if k.startswith(TENSOR_PREFIX))
        if found != sorted(listed):
            raise MiktError(f"{where}: the file carries {_some(found)} but its card lists {_some(listed)} "
                            "(tampered)")
        if listed and listed[0] != f"{name}.toml":
            raise MiktError(f"{where}: the carried files start with '{listed[0]}', not the spec {name}.toml "
                            "(tampered)")
        files = {}
        for path in listed:
            check_relative(path, where)
            t = tensors[TENSOR_PREFIX + path]
            if t.dtype != torch.uint8 or t.dim() != 1:
                raise MiktError(f"{where}: carried file '{path}' is a {t.dtype} tensor of shape {tuple(t.shape)}, "
                                "not bytes (tampered)")
            files[path] = t.numpy().tobytes()
        return cls(name, files)


def _some(paths: list[str]) -> str:
    return ", ".join(paths[:3]) + (f" (and {len(paths) - 3} more)" if len(paths) > 3 else "") if paths else "none"


def split_carried(tensors: dict[str, torch.Tensor]) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
    """A teacher file's tensors: (the policy's, the carried files')."""
    carried = {k: v for k, v in tensors.items() if k.startswith(TENSOR_PREFIX)}
    return {k: v for k, v in tensors.items() if k not in carried}, carried


def check_relative(path: str, where: Path | str) -> None:
    """A carried file's name must stay inside the folder it is written to."""
    pure = PurePosixPath(path)
    if (not path or pure.is_absolute() or str(pure) != path or "\\" in path or "\0" in path
            or any(part in ("", ".", "..") for part in pure.parts)):
        raise MiktError(f"{where}: carried file name {path!r} is not a plain relative path (tampered)")


@dataclass(frozen=True)
class ResolvedEnv:
    """An environment's spec and the file it was read from: a spec folder's, or a carried copy."""

    spec: AnySpec
    toml: Path
    copy_of: str | None = None  # None: found in the spec folders; else whose copy (run2, x@v1)
    where: str = ""  # the copy's place, as a message names it

    @property
    def name(self) -> SpecName:
        """The env's name bound to this spec: what evaluations and `make_env` take."""
        return SpecName(self.spec)

    @property
    def note(self) -> str | None:
        """What to tell the user when a carried copy stands in for the spec folders."""
        return None if self.copy_of is None else f"environment {self.detail}"

    @property
    def detail(self) -> str:
        return f"'{self.spec.name}' is in no spec folder: using the copy {self.copy_of} carries ({self.where})"


def folder_spec_file(name: str) -> Path | None:
    """Where `name`'s spec lies in the spec folders as every lookup finds it (yours first, then the shipped
    ones), or None."""
    if not SPEC_NAME_RE.fullmatch(name):
        return None
    for folder in spec_dirs():
        path = folder / f"{name}.toml"
        if path.is_file():
            return path
    return None


def _folders() -> str:
    return ", ".join(str(folder) for folder in spec_dirs())


# --- Reading and writing copies -------------------------------------------------------------------------------


def _relative(path: Path, folder: Path) -> str | None:
    """`path` relative to `folder` by name (symlinks not followed), or None when it lies outside."""
    relative = Path(os.path.relpath(os.path.abspath(path), os.path.abspath(folder)))
    return None if relative.parts[:1] == ("..",) else relative.as_posix()


def files_to_carry(env: ResolvedEnv) -> EnvFiles:
    """The spec file and its model's files, read from where `env` was found. NotCarried says why not."""
    folder = env.toml.parent
    paths = [env.toml]
    if isinstance(env.spec, MjcfSpec):
        if Path(env.spec.xml).expanduser().is_absolute():
            raise NotCarried(f"its spec names its XML by an absolute path ({env.spec.xml})")
        xml = env.spec.xml_path()
        paths += [xml, *model_files(xml)]
    relative, total = {}, 0
    for path in paths:
        rel = _relative(path, folder)
        if rel is None:
            raise NotCarried(f"its model loads {path}, outside the spec's folder {folder}")
        try:
            total += os.stat(path).st_size
        except OSError as err:
            raise MiktError(f"{path}: cannot be read: {err.strerror or err}") from err
        if total > limits.MAX_CARRIED_MODEL_BYTES:
            raise NotCarried(f"its spec and model files pass the {limits.MAX_CARRIED_MODEL_BYTES:,} bytes a run "
                             "or teacher carries")
        relative[rel] = path
    files = {rel: limits.read_file_bounded(path, str(path), limits.MAX_MODEL_FILE_BYTES)
             for rel, path in relative.items()}
    return EnvFiles(env.spec.name, files)


def _write_files(files: EnvFiles, folder: Path) -> None:
    folder.mkdir(parents=True)
    for rel, data in files.files.items():
        check_relative(rel, folder)
        target = folder / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        with open(target, "xb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())


def _outside(spec: AnySpec, folder: Path) -> Path | None:
    """A file the spec's model would read from outside `folder` (a path named absolutely), or None."""
    if not isinstance(spec, MjcfSpec):
        return None
    xml = spec.xml_path()
    return next((p for p in [xml, *model_files(xml)] if _relative(p, folder) is None), None)


def _open_copy(folder: Path, name: str, fingerprint: str, who: str, where: str, doing: str) -> ResolvedEnv:
    """The copy in `folder`, checked against `fingerprint`: a damaged or tampered copy is one line."""
    toml = folder / f"{name}.toml"
    what = f"{doing} {who}: the copy of environment '{name}' that {who} carries ({where})"
    hint = ("restore the copy from a backup, or put the spec into a spec folder (`mikt envs add`, or "
            "MIKT_ENVSPECS): a spec found there is used before any copy")
    try:
        spec = load_spec_file(toml)
        now = spec_fingerprint(spec)
        outside = _outside(spec, folder)
    except MiktError as err:
        raise MiktError(f"{what} is damaged: {err}", hint=hint) from None
    if now != fingerprint:
        raise MiktError(f"{what} does not match {who}'s card (spec and model files sha256 {fingerprint[:12]} "
                        f"recorded, {now[:12]} now): tampered or damaged", hint=hint)
    if outside is not None:
        raise MiktError(f"{what} reads {outside}, outside the copy (tampered)", hint=hint)
    return ResolvedEnv(spec, toml, copy_of=who, where=where)


def carry_into_run(run_path: Path, env: ResolvedEnv, fingerprint: str) -> None:
    """Write `env`'s files into `run_path/env/`, whole or not at all, after checking that the copy is the
    environment `fingerprint` describes and reads nothing outside itself. NotCarried says why a model cannot
    travel (nothing is written then); an environment that changed while it was copied is a MiktError."""
    files = files_to_carry(env)
    staging = run_path / f".{ENV_DIR}.{os.getpid()}.tmp"
    try:
        with deferred_interrupt():
            _write_files(files, staging)
            placed = load_spec_file(staging / f"{files.name}.toml")
            if spec_fingerprint(placed) != fingerprint:
                raise MiktError(f"environment '{files.name}' changed while it was copied into {run_path}",
                                hint="try again once its files are no longer being written")
            outside = _outside(placed, staging)
            if outside is not None:
                raise NotCarried(f"its model names {outside} by an absolute path")
            staging.rename(run_path / ENV_DIR)
    except OSError as err:
        raise MiktError(f"cannot write {run_path / ENV_DIR}: {err.strerror or err}",
                        hint="free some space or choose another --registry") from err
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)


def run_copy(run_path: Path, name: str) -> Path | None:
    """The folder of the copy a run carries, or None."""
    folder = run_path / ENV_DIR
    return folder if (folder / f"{name}.toml").is_file() else None


# A teacher's copy is written once per process, to a folder of its own named after its content (so two
# teachers carrying the same bytes share it), and removed when the process ends.
_written: dict[str, Path] = {}


def _remove_written() -> None:
    for folder in _written.values():
        shutil.rmtree(folder, ignore_errors=True)


atexit.register(_remove_written)


def _content_key(files: EnvFiles) -> str:
    digest = hashlib.sha256()
    for rel, data in files.files.items():
        digest.update(rel.encode() + b"\0" + len(data).to_bytes(8, "little") + data)
    return digest.hexdigest()


def _teacher_copy(files: EnvFiles, fingerprint: str, who: str, doing: str) -> ResolvedEnv:
    key = _content_key(files)
    folder = _written.get(key)
    if folder is None or not folder.is_dir():
        folder = Path(tempfile.mkdtemp(prefix="mikt-env-")) / "env"
        try:
            _write_files(files, folder)
        except OSError as err:
            shutil.rmtree(folder.parent, ignore_errors=True)
            raise MiktError(f"{doing} {who}: cannot write the copy of environment '{files.name}' it carries to "
                            f"{folder}: {err.strerror or err}", hint="free some space in the temporary folder "
                            "(TMPDIR)") from err
        _written[key] = folder
    return _open_copy(folder, files.name, fingerprint, who, "in its file", doing)


def teacher_files(name: str, fingerprint: str, run_path: Path | None = None,
                  env: ResolvedEnv | None = None) -> EnvFiles:
    """The files a teacher on `name` carries: those of its run's own copy where it has one (what it trained
    on, whatever the spec folders hold now), else those of `env` (else the spec folders'), checked against
    `fingerprint` as a run's copy is. NotCarried says why not; the teacher is then published without them."""
    try:
        if run_path is not None and (folder := run_copy(run_path, name)) is not None:
            env = _open_copy(folder, name, fingerprint, run_path.name, str(folder), "publishing from")
        elif env is None:
            env = resolve_new_env(name)
    except MiktError as err:
        raise NotCarried(str(err)) from None
    files = files_to_carry(env)
    with tempfile.TemporaryDirectory(prefix="mikt-env-") as tmp:
        folder = Path(tmp) / "env"
        _write_files(files, folder)
        placed = load_spec_file(folder / f"{files.name}.toml")
        if spec_fingerprint(placed) != fingerprint:
            raise NotCarried(f"environment '{name}' changed since it was trained")
        outside = _outside(placed, folder)
        if outside is not None:
            raise NotCarried(f"its model names {outside} by an absolute path")
    return files


# --- Lookups --------------------------------------------------------------------------------------------------


def resolve_new_env(name: str, teachers: Iterable[tuple[TeacherCard, EnvFiles | None]] = ()) -> ResolvedEnv:
    """A new run's environment: the spec folders, else the copy one of `teachers` carries (two teachers
    carrying different bodies under that name are refused rather than one picked)."""
    path = folder_spec_file(name)
    if path is not None:
        return ResolvedEnv(load_spec_file(path), path)
    copies: dict[str, tuple[str, EnvFiles]] = {}
    for card, files in teachers:
        if card.env == name and files is not None and card.env_fingerprint is not None:
            copies.setdefault(card.env_fingerprint, (card.ref, files))
    if len(copies) > 1:
        refs = [ref for ref, _ in copies.values()]
        raise MiktError(f"environment '{name}' is in no spec folder ({_folders()}), and teachers {refs[0]} and "
                        f"{refs[1]} carry different bodies under that name",
                        hint=f"add the one you mean to a spec folder (mikt envs add), or {NO_COPY_HINT}")
    if copies:
        fingerprint, (ref, files) = next(iter(copies.items()))
        return _teacher_copy(files, fingerprint, ref, "cannot start a run on")
    spec = load_spec(name)  # raises: an invalid name, or the unknown environment and the known ones
    return ResolvedEnv(spec, folder_spec_file(name) or Path(f"{name}.toml"))


def resolve_run_env(run_path: Path, run_id: str, name: str, fingerprint: str | None, doing: str) -> ResolvedEnv:
    """A run's environment, in the lookup order above. `doing` starts the message of a refusal
    ("cannot train", "cannot evaluate")."""
    copy = run_copy(run_path, name)
    path = folder_spec_file(name)
    if path is not None:
        spec = load_spec_file(path)
        if fingerprint is not None:  # a run recorded before mikt kept fingerprints is taken as it is
            now = spec_fingerprint(spec)
            if now != fingerprint:
                raise MiktError(
                    f"{doing} {run_id}: " + describe_change(name, fingerprint, now, "it started"),
                    hint=f"restore the spec (the run's card holds it: mikt inspect {run_id} --json), or add the "
                         "edited body under a new name for new runs"
                         + (f"; {run_id} carries its own copy, used when no spec folder has '{name}'"
                            if copy is not None else ""))
        return ResolvedEnv(spec, path)
    if copy is None or fingerprint is None:
        raise MiktError(f"{doing} {run_id}: environment '{name}' is in no spec folder ({_folders()}), and "
                        f"{run_id} carries no copy of it (runs made before mikt carried their environment, and "
                        "models that lie outside their spec's folder, carry none)", hint=NO_COPY_HINT)
    return _open_copy(copy, name, fingerprint, run_id, str(copy), doing)


def resolve_teacher_env(card: TeacherCard, files: EnvFiles | None, doing: str) -> ResolvedEnv:
    """A teacher's environment, in the lookup order above. A spec found in the folders is compared with the
    card's copy field by field (a field added to mikt's specs since keeps its default), and with its
    fingerprint where the card has one (an edited model file)."""
    path = folder_spec_file(card.env)
    if path is not None:
        spec = load_spec_file(path)
        now = spec_record(spec)
        changed = sorted(k for k in card.env_spec.keys() & now.keys() if card.env_spec[k] != now[k])
        hint = "restore the spec, or add the edited body under a new name and train on it" + (
            f"; {card.ref} carries its own copy, used when no spec folder has '{card.env}'" if files else "")
        if changed:
            raise MiktError(f"{doing} {card.ref}: environment '{card.env}' changed since it was trained "
                            f"({', '.join(f'{k}: {card.env_spec[k]!r} then, {now[k]!r} now' for k in changed[:3])})",
                            hint=hint)
        if card.env_fingerprint is not None and (now_fp := spec_fingerprint(spec)) != card.env_fingerprint:
            raise MiktError(f"{doing} {card.ref}: " + describe_change(card.env, card.env_fingerprint, now_fp,
                                                                      "it was trained"), hint=hint)
        return ResolvedEnv(spec, path)
    if files is None or card.env_fingerprint is None:
        raise MiktError(f"{doing} {card.ref}: environment '{card.env}' is in no spec folder ({_folders()}), and "
                        f"{card.ref} carries no copy of it", hint=NO_COPY_HINT)
    return _teacher_copy(files, card.env_fingerprint, card.ref, doing)


def why_no_copy(run_path: Path, name: str) -> str | None:
    """Why a run carries no copy of its environment; None when it carries one (or its spec is in no spec
    folder, where the reason cannot be told)."""
    if run_copy(run_path, name) is not None:
        return None
    path = folder_spec_file(name)
    if path is None:
        return None
    try:
        files_to_carry(ResolvedEnv(load_spec_file(path), path))
    except NotCarried as why:
        return str(why)
    except MiktError as err:
        return str(err)
    return "it was made before mikt carried environments"
