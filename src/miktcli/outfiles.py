"""Files a user names for output (plots, frames, videos): refused early when they cannot be written, and
written whole or not at all."""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from miktcli.errors import MiktError

FULL_DISK_BYTES = 1024 * 1024  # less free space than this beside a failed video: the disk filled up


def prepare_output(path: Path) -> Path:
    """`path` as a file that can be written, checked by creating a file beside it (permission bits and
    os.access say nothing of read-only mounts, /proc, or root's view). Folders made for the check are removed
    again, so a command that fails later leaves none behind; the write makes them for good."""
    path = Path(path)
    if path.is_dir():
        raise MiktError(f"{path} is a folder; give a file name such as {path / 'out'}{path.suffix or '.png'}")
    made = [p for p in [path.parent, *path.parent.parents] if not p.exists()]
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path.parent, prefix=f".{path.name}.", suffix=".probe"):
            pass
    except OSError as err:
        raise MiktError(f"cannot write {path}: {err.strerror or err}", hint="choose another path") from None
    finally:
        for folder in made:  # deepest first
            with suppress(OSError):
                folder.rmdir()
    return path


@contextmanager
def atomic_output(path: Path, suffix: str) -> Iterator[Path]:
    """A temporary file beside `path` (ending in `suffix`, which writers read the format from) that becomes
    `path` when the block succeeds; on failure it is removed and `path` is left as it was."""
    path = prepare_output(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.part{suffix}")
    try:
        yield tmp
        tmp.replace(path)
    except (OSError, RuntimeError, ValueError) as err:  # encoders (ffmpeg, png) fail with these
        tmp.unlink(missing_ok=True)
        if isinstance(err, BrokenPipeError) or "Broken pipe" in str(err):
            # an encoder process (ffmpeg) that stopped: most often because the disk filled up under it
            full = shutil.disk_usage(path.parent).free < FULL_DISK_BYTES
            raise MiktError(f"could not write {path}: " + ("No space left on device" if full else
                                                           "the video encoder (ffmpeg) stopped"),
                            hint="free some space and run again" if full else None) from None
        if isinstance(err, OSError) and err.strerror:
            raise  # the CLI names permissions, full disks and the like itself
        first = str(err).strip().splitlines()[0] if str(err).strip() else ""  # encoders add pages of detail
        raise MiktError(f"could not write {path}: {type(err).__name__}: {first}") from err
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
