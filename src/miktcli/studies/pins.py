"""A study's teacher pins (`teachers.json` in its folder): each teacher reference of its grid → the exact
version and file its cells train with.

A reference without a version (`hopper`, `hopper@latest`) means the newest version, and that changes when a
teacher of the same name is trained or imported (`teacher import` names a teacher after its env): a study
resolving it per cell would mix teachers in one row. So a study resolves each reference once, when it is
first prepared, and every later cell uses that version. The sha256 guards against a registry whose version
of that name is another file (another machine's).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, RootModel, ValidationError

from miktcli.errors import MiktError, describe_validation_error
from miktcli.registry.files import write_text_atomic
from miktcli.registry.teachers import REF_RE, read_teacher_card, resolve

PINS_FILE = "teachers.json"
RESET_HINT = "restore it, or move it away to pin the versions this registry holds now"


class Pin(BaseModel):
    model_config = ConfigDict(extra="forbid")

    ref: str = Field(pattern=r"^[^@]+@v\d+$")  # always a version
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")


class Pins(RootModel[dict[str, Pin]]):
    pass


def read_pins(path: Path) -> dict[str, Pin]:
    if not path.exists():
        return {}
    try:
        pins = Pins.model_validate(json.loads(path.read_bytes().decode("utf-8"))).root
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as err:
        raise MiktError(f"{path}: damaged teacher pins: {type(err).__name__}: {err}", hint=RESET_HINT) from None
    except ValidationError as err:
        raise MiktError(f"{path}: damaged teacher pins: {describe_validation_error(err)}", hint=RESET_HINT) from None
    for ref, pin in pins.items():
        if not can_mean(ref, pin.ref):
            raise MiktError(f"{path}: damaged teacher pins: `{ref}` cannot mean {pin.ref}", hint=RESET_HINT)
    return pins


def write_pins(path: Path, pins: dict[str, Pin]) -> None:
    write_text_atomic(path, json.dumps({ref: pin.model_dump() for ref, pin in pins.items()}, indent=2))


def can_mean(ref: str, versioned: str) -> bool:
    """Whether a grid's reference (`name`, `name@latest`, `name@vN`) can stand for `name@vN`."""
    m, v = REF_RE.fullmatch(ref), REF_RE.fullmatch(versioned)
    return bool(m and v) and m.group("name") == v.group("name") and m.group("version") in (
        None, "latest", v.group("version"))


def pin_now(registry: Path, ref: str) -> Pin:
    """The version `ref` means in `registry` now (its file header only is read)."""
    path = resolve(registry, ref)
    return Pin(ref=f"{path.parent.name}@{path.stem}", sha256=read_teacher_card(path).tensors_sha256)


def check_pin(registry: Path, path: Path, ref: str, pin: Pin) -> None:
    """The pinned version must be in this registry and be the pinned file."""
    found = read_teacher_card(resolve(registry, pin.ref)).tensors_sha256
    if found != pin.sha256:
        raise MiktError(f"{path}: pinned `{ref}` to {pin.ref} (sha256 {pin.sha256[:12]}), but {pin.ref} in "
                        f"{registry} is another file (sha256 {found[:12]})",
                        hint="use the registry the study was prepared with, or move teachers.json away to pin "
                             "the versions this registry holds")


class TeacherPins:
    """The pins of one study folder: read once, completed for the references that have none, checked."""

    def __init__(self, out_dir: Path):
        self.path = Path(out_dir) / PINS_FILE
        self.pins: dict[str, Pin] = {}
        self.new: list[tuple[str, Pin]] = []  # (grid reference, pin) pinned by the last `pin`

    def pin(self, registry: Path, refs: list[str], used: Callable[[list[str]], dict[str, Pin]]) -> None:
        """Each reference → one version for the whole study: its pin in teachers.json, else `used(missing)`'s
        (the version the study's earliest run trained with: a study prepared before pins existed), else the
        version it means now. Checked against this registry's files before any cell is created."""
        self.pins, self.new = read_pins(self.path), []
        missing = [ref for ref in refs if ref not in self.pins]
        earlier = used(missing) if missing else {}
        for ref in missing:
            pin = earlier.get(ref) or pin_now(registry, ref)
            self.pins[ref] = pin
            self.new.append((ref, pin))
        for ref in refs:
            check_pin(registry, self.path, ref, self.pins[ref])
        if self.new:
            write_pins(self.path, self.pins)

    def ref(self, grid_ref: str) -> str:
        """The exact version a grid reference stands for in this study (after `pin`)."""
        return self.pins[grid_ref].ref
