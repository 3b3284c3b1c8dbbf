"""Writes that are all-or-nothing: a crash or Ctrl-C never leaves a half-written file behind."""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Iterator
from pathlib import Path


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
