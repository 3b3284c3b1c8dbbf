"""Files a user names for output (plots, frames, videos): refused early when they cannot be written, and
written whole or not at all."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from miktcli.errors import MiktError


def prepare_output(path: Path) -> Path:
    """`path` as a file that can be written: not a folder, its folder created and writable."""
    path = Path(path)
    if path.is_dir():
        raise MiktError(f"{path} is a folder; give a file name such as {path / 'out'}{path.suffix or '.png'}")
    path.parent.mkdir(parents=True, exist_ok=True)
    if not os.access(path.parent, os.W_OK):
        raise MiktError(f"cannot write {path}: {path.parent} is not writable (read-only or no permission)",
                        hint="choose another path")
    return path


@contextmanager
def atomic_output(path: Path, suffix: str) -> Iterator[Path]:
    """A temporary file beside `path` (ending in `suffix`, which writers read the format from) that becomes
    `path` when the block succeeds; on failure it is removed and `path` is left as it was."""
    path = prepare_output(path)
    tmp = path.with_name(f".{path.stem}.part{suffix}")
    try:
        yield tmp
        tmp.replace(path)
    except (OSError, RuntimeError, ValueError) as err:  # encoders (ffmpeg, png) fail with these
        tmp.unlink(missing_ok=True)
        if isinstance(err, OSError) and err.strerror:
            raise  # the CLI names permissions, full disks and the like itself
        raise MiktError(f"could not write {path}: {type(err).__name__}: {err}") from err
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
