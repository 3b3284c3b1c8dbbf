"""safetensors files that carry a pydantic card as JSON in their metadata, with a sha256 of the tensors.

safetensors cannot execute code on load (unlike pickle), and its header can be read without the tensors.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import TypeVar

import torch
from pydantic import BaseModel, ValidationError
from safetensors import SafetensorError, safe_open
from safetensors.torch import load, save

from miktcli.atomic import write_bytes_atomic
from miktcli.errors import MiktError, describe_validation_error

CARD_KEY = "mikt_card"
CardT = TypeVar("CardT", bound=BaseModel)


def tensors_sha256(tensors: dict[str, torch.Tensor]) -> str:
    """Hash of names, dtypes, shapes and bytes, in name order: independent of file layout."""
    h = hashlib.sha256()
    for name in sorted(tensors):
        t = tensors[name].contiguous()
        h.update(f"{name}|{t.dtype}|{tuple(t.shape)}\n".encode())
        h.update(t.view(-1).view(torch.uint8).numpy().tobytes() if t.numel() else b"")
    return h.hexdigest()


def save_with_card(path: Path, tensors: dict[str, torch.Tensor], card: BaseModel, exclusive: bool = False) -> None:
    """`tensors` must be contiguous and share no memory (our parameters are views of one flat buffer): every
    caller already cloned them to hash them, so they are not copied again here."""
    data = save(tensors, metadata={CARD_KEY: card.model_dump_json()})
    write_bytes_atomic(path, data, exclusive=exclusive)


def read_metadata(path: Path) -> dict[str, str]:
    try:
        with safe_open(str(path), framework="pt") as f:
            return f.metadata() or {}
    except (SafetensorError, OSError, ValueError) as err:
        raise MiktError(f"{path}: not a readable safetensors file (truncated or corrupted): {err}") from err


def read_card(path: Path, card_type: type[CardT], schema_version: int) -> CardT:
    meta = read_metadata(path)
    if CARD_KEY not in meta:
        raise MiktError(f"{path}: safetensors file without a mikt card")
    try:
        raw = json.loads(meta[CARD_KEY])
    except json.JSONDecodeError as err:
        raise MiktError(f"{path}: the card is not valid JSON: {err}") from err
    found = raw.get("schema_version") if isinstance(raw, dict) else None
    if isinstance(found, int) and found > schema_version:
        raise MiktError(
            f"{path}: card schema version {found} is newer than this mikt understands ({schema_version})",
            hint="upgrade mikt to read it",
        )
    try:
        return card_type.model_validate(raw)
    except ValidationError as err:
        raise MiktError(f"{path}: invalid card, {describe_validation_error(err)}") from err


def read_tensors(path: Path) -> dict[str, torch.Tensor]:
    try:
        return load(Path(path).read_bytes())
    except (SafetensorError, OSError, ValueError) as err:
        raise MiktError(f"{path}: not a readable safetensors file (truncated or corrupted): {err}") from err


def verify_sha(path: Path, tensors: dict[str, torch.Tensor], expected: str) -> None:
    actual = tensors_sha256(tensors)
    if actual != expected:
        raise MiktError(
            f"{path}: tensors do not match the card's sha256 (tampered or corrupted): "
            f"card {expected[:12]}…, file {actual[:12]}…"
        )
