"""The teacher registry: registry/teachers/NAME/vN.safetensors, immutable versions, `latest` alias.

Lookups see two layers: the local registry, and below it the teachers packaged with mikt (read-only, see
registry/packaged.py). A local file of the same name and version wins; a new version is numbered above both.

`latest` is the highest version present, derived from the files themselves: there is no index that a
crash could leave half-updated.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import torch

from miktcli import limits
from miktcli.engine.policies import GaussianActorCritic
from miktcli.errors import MiktError
from miktcli.registry import location
from miktcli.registry.cards import TEACHER_SCHEMA_VERSION, TeacherCard, TeacherVersion
from miktcli.registry.carried import EnvFiles, split_carried
from miktcli.registry.files import read_card, read_tensors, save_with_card, tensors_sha256, verify_sha
from miktcli.registry.packaged import packaged_teachers
from miktcli.registry.runs import Run, check_registry

NAME_RE = re.compile(r"^[a-z0-9][a-z0-9._-]*$")
MAX_NAME_LENGTH = 64
# `eval` and `inspect` read these as runs (runN, last) or as a version alias: a teacher may not take them.
RESERVED_NAME_RE = re.compile(r"^(run\d+|last|latest)$")
REF_RE = re.compile(r"^(?P<name>[^@]+)(@(?P<version>v\d+|latest))?$")
VERSION_FILE_RE = re.compile(r"^v(\d+)\.safetensors$")


def teachers_dir(registry: Path) -> Path:
    return Path(registry) / "teachers"


def check_name(name: str) -> str:
    """Teacher names are also folder names: no path separators, no '..', nothing a run id could be."""
    if not name:
        raise MiktError("teacher name is empty")
    if len(name) > MAX_NAME_LENGTH:
        raise MiktError(f"teacher name '{name[:20]}…' is {len(name)} characters long; at most {MAX_NAME_LENGTH}")
    if not NAME_RE.fullmatch(name) or ".." in name:
        raise MiktError(f"invalid teacher name {name!r}: use lowercase letters, digits, '.', '_' and '-', "
                        "starting with a letter or digit")
    if RESERVED_NAME_RE.fullmatch(name):
        raise MiktError(f"teacher name '{name}' is reserved: eval and inspect read it as a run or an alias",
                        hint="to teach with a run's student, add it as a teacher first: mikt teacher add RUN "
                             "--name NAME" if name.startswith("run") else None)
    return name


@dataclass(frozen=True)
class TeacherFile:
    """One teacher version as lookups see it: the local registry's file, or the packaged one below it."""

    name: str
    version: int
    path: Path
    source: str  # "local" or "packaged"
    shadows_packaged: bool = False  # a local file that hides a packaged one of the same name and version

    @property
    def ref(self) -> str:
        return f"{self.name}@v{self.version}"


def _local_versions(registry: Path, name: str) -> list[int]:
    folder = teachers_dir(registry) / name
    if not folder.is_dir():
        return []
    found = (VERSION_FILE_RE.fullmatch(p.name) for p in folder.iterdir())
    return sorted(int(m.group(1)) for m in found if m)


def teacher_files(registry: Path, name: str | None = None) -> list[TeacherFile]:
    """Every teacher version of both layers (or of one name), by name then version. A local file of the same
    name and version wins over the packaged one."""
    check_registry(registry)
    root = teachers_dir(registry)
    packaged = packaged_teachers()
    if name is not None:
        local_names = [name] if (root / name).is_dir() else []
        packaged = {name: packaged[name]} if name in packaged else {}
    else:
        local_names = [p.name for p in root.iterdir() if p.is_dir()] if root.is_dir() else []
    files: dict[tuple[str, int], TeacherFile] = {}
    for n, (v, path) in packaged.items():
        files[(n, v)] = TeacherFile(n, v, path, "packaged")
    for n in local_names:
        for v in _local_versions(registry, n):
            path = root / n / f"v{v}.safetensors"
            below = files.get((n, v))  # in a source checkout run from its root, both layers are the same file
            files[(n, v)] = TeacherFile(n, v, path, "local",
                                        shadows_packaged=below is not None and below.path != path.resolve())
    return [files[k] for k in sorted(files)]


def list_names(registry: Path) -> list[str]:
    return sorted({f.name for f in teacher_files(registry)})


def versions(registry: Path, name: str) -> list[int]:
    """The versions of `name` in both layers: a new version is numbered above all of them."""
    return [f.version for f in teacher_files(registry, name)]


def find(registry: Path, ref: str) -> TeacherFile:
    """`name`, `name@latest` or `name@vN` → the file that wins; unknown names and versions list what exists."""
    m = REF_RE.fullmatch(ref)
    if not m:
        raise MiktError(f"invalid teacher reference '{ref}': expected NAME or NAME@vN")
    name, version = m.group("name"), m.group("version")
    check_name(name)  # a reference is never a path: '../x' or '/abs' are refused here
    known = teacher_files(registry, name)
    if not known:
        names = ", ".join(list_names(registry)) or "(none)"
        raise MiktError(f"unknown teacher '{name}' in registry {location.describe(registry)}; known: {names}",
                        hint=f"train one with: mikt teacher train ENV --name {name}, or read another registry "
                        f"(set {location.ENV_VAR} or pass --registry)")
    number = known[-1].version if version in (None, "latest") else int(version[1:])
    for f in known:
        if f.version == number:
            return f
    raise MiktError(f"teacher '{name}' has no version v{number}; versions: "
                    + ", ".join(f"v{f.version}" for f in known))


def resolve(registry: Path, ref: str) -> Path:
    return find(registry, ref).path


def check_card_against_tensors(path: Path, card: TeacherCard, tensors: dict[str, torch.Tensor]) -> None:
    """The card's dims and layer sizes must be those of the stored tensors, and the tensors exactly the
    policy's: nothing missing, nothing extra."""
    wanted = set(GaussianActorCritic(card.obs_dim, card.act_dim, card.pi_hidden, card.vf_hidden).state_dict())
    missing, extra = sorted(wanted - set(tensors)), sorted(set(tensors) - wanted)
    if missing:
        raise MiktError(f"{path}: tensor '{missing[0]}' is missing" + (f" (and {len(missing) - 1} more)"
                                                                        if len(missing) > 1 else ""))
    if extra:
        raise MiktError(f"{path}: unexpected tensor '{extra[0]}' for the layers the card lists"
                        + (f" (and {len(extra) - 1} more)" if len(extra) > 1 else ""))

    def shape(key: str) -> tuple[int, ...]:
        return tuple(tensors[key].shape)

    expected = {"obs_normalizer.mean": (card.obs_dim,), "log_std": (card.act_dim,)}
    for net, hidden, n_out in (("pi", card.pi_hidden, card.act_dim), ("vf", card.vf_hidden, 1)):
        sizes = [card.obs_dim, *hidden]
        for j, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
            expected[f"{net}.hidden.{j}.weight"] = (b, a)
        expected[f"{net}.head.weight"] = (n_out, sizes[-1])
    for key, want in expected.items():
        got = shape(key)
        if got != want:
            raise MiktError(f"{path}: card disagrees with tensor '{key}': card implies {want}, tensor is {got}")
    not_finite = [k for k, v in tensors.items() if v.is_floating_point() and not torch.isfinite(v).all()]
    if not_finite:  # a diverged or broken policy: every action it gave would be NaN
        raise MiktError(f"{path}: tensor '{not_finite[0]}' holds NaN or infinite values")
    spec = card.env_spec
    if (spec.get("obs_dim"), spec.get("act_dim")) != (card.obs_dim, card.act_dim):
        raise MiktError(f"{path}: card and tensors say obs {card.obs_dim} / act {card.act_dim} but its env "
                        f"'{card.env}' has obs {spec.get('obs_dim')} / act {spec.get('act_dim')}")


def read_teacher_card(path: Path) -> TeacherCard:
    return read_card(path, TeacherCard, TEACHER_SCHEMA_VERSION)


@dataclass
class Teacher:
    card: TeacherCard
    path: Path
    policy: GaussianActorCritic
    source: str = "local"  # or "packaged": where the lookup found it
    carried: EnvFiles | None = None  # the environment the file carries (registry/carried.py)


def load_policy_file(path: Path) -> tuple[TeacherCard, GaussianActorCritic]:
    """Read and fully verify a policy file (a teacher or a run's student): card, shapes and sha256."""
    card, policy, _ = load_policy_file_with_env(path)
    return card, policy


def load_policy_file_with_env(path: Path) -> tuple[TeacherCard, GaussianActorCritic, EnvFiles | None]:
    """As load_policy_file, and the environment files the file carries (checked against the card's list
    here, against its fingerprint when they are used)."""
    card = read_teacher_card(path)
    tensors, carried = split_carried(read_tensors(path))
    env = EnvFiles.from_tensors(path, card.env, card.env_files, carried) if carried or card.env_files else None
    check_card_against_tensors(path, card, tensors)
    verify_sha(path, tensors, card.tensors_sha256)
    if carried or card.env_files_sha256 is not None:
        verify_sha(path, carried, card.env_files_sha256 or "none")
    policy = GaussianActorCritic(card.obs_dim, card.act_dim, card.pi_hidden, card.vf_hidden, card.activation)
    policy.load_state_dict(tensors)
    policy.obs_normalizer.frozen = True
    policy.obs_normalizer.clip = math.inf if card.obs_clip is None else card.obs_clip
    return card, policy, env


def load_teacher(registry: Path, ref: str) -> Teacher:
    """Load a verified teacher, frozen: normaliser statistics fixed, no gradients for its parameters."""
    found = find(registry, ref)
    path = found.path
    card, policy, env = load_policy_file_with_env(path)
    stored_as = TeacherVersion(path.parent.name, int(path.stem[1:]))
    if (card.name, card.version) != stored_as:
        raise MiktError(f"{path}: the card names {card.ref} but the file is stored as {stored_as} "
                        "(moved or tampered)")
    policy.requires_grad_(False)
    policy.eval()
    return Teacher(card, path, policy, found.source, env)


def publish_teacher(registry: Path, card: TeacherCard, policy: GaussianActorCritic,
                    env: EnvFiles | None = None) -> TeacherCard:
    """Write the next version of `card.name` into the local registry, numbered above the versions of both
    layers (so `hopper` trained beside the packaged hopper@v2 becomes hopper@v3, and `latest` means the newest
    either way). The file appears whole or not at all, and is never replaced. With `env`, the file carries
    those environment files (`card.env_fingerprint` describes them) unless it would then pass the size a
    teacher file may take; the card's `env_files` says what it carries."""
    check_name(card.name)
    tensors = {k: v.detach().clone().contiguous() for k, v in policy.state_dict().items()}
    policy_bytes = sum(t.numel() * t.element_size() for t in tensors.values())
    if env is not None and policy_bytes + env.size + limits.MiB > limits.MAX_TENSOR_FILE_BYTES:
        env = None
    carried = env.tensors() if env is not None else {}
    for _ in range(100):  # another process may take the same number first: try the next one
        number = (versions(registry, card.name) or [0])[-1] + 1
        final = card.model_copy(update={"version": number, "tensors_sha256": tensors_sha256(tensors),
                                        "schema_version": TEACHER_SCHEMA_VERSION,
                                        "env_files": list(env.files) if env is not None else [],
                                        "env_files_sha256": tensors_sha256(carried) if carried else None})
        path = teachers_dir(registry) / card.name / f"v{number}.safetensors"
        try:
            save_with_card(path, {**tensors, **carried}, final, exclusive=True)
            return final
        except FileExistsError:
            continue
    raise MiktError(f"could not allocate a version for teacher '{card.name}'")


def load_run_teachers(run: Run, registry: Path) -> list[Teacher]:
    """The exact teacher versions a run was started with; a changed file is refused."""
    teachers = []
    for ref in run.card.teachers:
        t = load_teacher(registry, ref.ref)
        if t.card.tensors_sha256 != ref.sha256:
            raise MiktError(f"run '{run.id}': teacher '{t.card.ref}' is not the one the run started with "
                            f"(sha256 {t.card.tensors_sha256[:12]}… vs {ref.sha256[:12]}…)")
        teachers.append(t)
    return teachers
