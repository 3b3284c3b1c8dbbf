"""A study folder's state: `state.json` (which run holds which cell) and the lock of the one process that
drives the study. Reading the folder needs no lock; preparing cells takes it (`StudyState.driving`)."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from miktcli.errors import MiktError
from miktcli.registry.files import write_text_atomic
from miktcli.registry.locks import FileLock, lock_holder
from miktcli.registry.runs import run_number

STATE_FILE = "state.json"
LOCK_FILE = ".lock"  # in the study folder: held by the one process driving the study


def read_state(path: Path) -> dict[str, str]:
    """A state.json's cell → run id map ({} where there is none yet); a damaged one is a one-line error."""
    if not path.exists():
        return {}
    try:
        cells = json.loads(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as err:
        raise MiktError(f"{path}: damaged study state: {type(err).__name__}: {err}",
                        hint="restore it, or move it away to start the study afresh") from err
    if not (isinstance(cells, dict) and all(isinstance(k, str) and isinstance(v, str) for k, v in cells.items())):
        raise MiktError(f"{path}: damaged study state: expected an object of cell → run id",
                        hint="restore it, or move it away to start the study afresh")
    return cells


def by_run_number(cells: dict[str, str]) -> list[tuple[str, str]]:
    """The (cell, run id) pairs in the order their runs were created (run9 before run10)."""
    return sorted(cells.items(), key=lambda cell_run: run_number(cell_run[1]))


class StudyState:
    """cell → run id, as state.json holds it, and the folder's driver lock. `adopt` maps a state read from
    the file onto today's cell keys (a state.json of an older mikt)."""

    def __init__(self, out_dir: Path, adopt: Callable[[dict[str, str]], dict[str, str]]):
        self.out_dir = Path(out_dir)
        self.path = self.out_dir / STATE_FILE
        self.lock = FileLock(self.out_dir / LOCK_FILE)
        self._adopt = adopt
        self._driving = 0  # depth of `driving()` blocks: the lock is kept until the outermost one ends
        self.cells: dict[str, str] = {}
        self.load()

    def load(self) -> None:
        self.cells = self._adopt(read_state(self.path))

    @contextmanager
    def driving(self) -> Iterator[StudyState]:
        """Drive the study: the first `take_lock` inside takes the study folder's lock, and it is kept until
        the block ends, so that no second driver trains the same cells (two drivers each trained every cell,
        and state.json and results.md then named different runs)."""
        self._driving += 1
        try:
            yield self
        finally:
            self._driving -= 1
            if not self._driving:
                self.lock.release()

    def take_lock(self) -> None:
        """The study folder's lock, then state.json as it is now (another driver may have written it since
        this object read it)."""
        if self.lock.held:
            return
        try:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            taken = self.lock.try_acquire()  # creates a file: also the check that the folder is writable
        except OSError as err:  # before any run exists: else each try leaves one behind
            raise MiktError(f"cannot write the study's results to {self.out_dir}: {err.strerror or err}",
                            hint="choose another --out") from None
        if not taken:
            owner = lock_holder(self.lock.path)
            raise MiktError(f"{self.out_dir} is driven by another `mikt study` (pid {owner if owner else '?'})",
                            hint="wait for it to end, or stop it (Ctrl-C or SIGTERM) and start again; "
                                 "--report-only reads the folder meanwhile")
        self.load()

    def remember(self, key: str, run_id: str, write: bool = True) -> None:
        self.cells[key] = run_id
        if write:
            self.write()

    def write(self) -> None:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        write_text_atomic(self.path, json.dumps(self.cells, indent=2, ensure_ascii=False))
