"""Everything written to disk goes through here: all-or-nothing writes (a crash or Ctrl-C never leaves a
half-written file behind), and safetensors files that carry a pydantic card as JSON in their metadata with a
sha256 of the tensors.

safetensors cannot execute code on load (unlike pickle), and its header can be read without the tensors.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import signal
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import TypeVar

import torch
from pydantic import BaseModel, ValidationError
from safetensors import SafetensorError, safe_open
from safetensors.torch import load, save

from miktcli import limits
from miktcli.errors import MiktError, describe_validation_error
from miktcli.limits import read_file_bounded


@contextlib.contextmanager
def deferred_interrupt() -> Iterator[None]:
    """Hold a Ctrl-C (or SIGTERM) that arrives inside the block until the block is done, then raise it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []
    signals = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, lambda signum, frame: received.append(signum)) for s in signals}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        for s in dict.fromkeys(received):  # now deliver what was held, as it would have been
            handler = previous[s]
            if callable(handler):
                handler(s, None)  # Python's Ctrl-C handler (and the CLI's SIGTERM one) raise KeyboardInterrupt
            elif handler == signal.SIG_DFL:
                signal.raise_signal(s)


def _tmp_path(path: Path) -> Path:
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def write_bytes_atomic(path: Path, data: bytes, exclusive: bool = False) -> None:
    """Write to a temp file, fsync, then rename into place. With exclusive, never replace an existing file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _tmp_path(path)
    with deferred_interrupt():
        try:
            with open(tmp, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            if exclusive:
                os.link(tmp, path)  # fails with FileExistsError instead of overwriting
                os.unlink(tmp)
            else:
                os.replace(tmp, path)
        finally:
            if tmp.exists():
                tmp.unlink()


def write_text_atomic(path: Path, text: str) -> None:
    write_bytes_atomic(path, text.encode())


def append_line(path: Path, line: str) -> None:
    """Append one whole line (a JSONL record); the line is written with a single write call."""
    with deferred_interrupt(), open(path, "a") as f:
        f.write(line.rstrip("\n") + "\n")
        f.flush()


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
    limits.require_regular_file(path, str(path))  # safetensors would block on a FIFO, deaf to Ctrl-C
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
        return load(read_file_bounded(path, str(path), limits.MAX_TENSOR_FILE_BYTES))
    except (SafetensorError, OSError, ValueError) as err:
        raise MiktError(f"{path}: not a readable safetensors file (truncated or corrupted): {err}") from err


def verify_sha(path: Path, tensors: dict[str, torch.Tensor], expected: str) -> None:
    actual = tensors_sha256(tensors)
    if actual != expected:
        raise MiktError(
            f"{path}: tensors do not match the card's sha256 (tampered or corrupted): "
            f"card {expected[:12]}…, file {actual[:12]}…"
        )
