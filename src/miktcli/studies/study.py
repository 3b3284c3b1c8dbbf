"""A study's plan and state: pairs × methods × seeds on one budget, resumable.

A grid file (TOML) names the pairs, methods and seeds; the study prepares each cell as an ordinary transfer
run (the same code path as `mikt transfer`), remembers which run holds which cell in `state.json`, and
skips finished cells when started again. An executor (studies.serial, studies.ray_executor) trains the
prepared cells; `report` aggregates whatever has finished.
"""

from __future__ import annotations

import functools
import json
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from miktcli import compat
from miktcli.engine.ppo import PPOConfig
from miktcli.envs.fingerprint import describe_change, spec_fingerprint
from miktcli.envs.spec import load_spec
from miktcli.errors import MiktError
from miktcli.registry import location
from miktcli.registry.cards import TeacherRef
from miktcli.registry.files import write_text_atomic
from miktcli.registry.locks import FileLock, lock_holder
from miktcli.registry.runs import Run, lock_owner, open_run, run_number, runs_dir
from miktcli.registry.teachers import REF_RE, resolve
from miktcli.studies.grid import Grid, MethodSpec, PairSpec, cell_key
from miktcli.studies.pins import PINS_FILE, Pin, check_pin, pin_now, read_pins, write_pins
from miktcli.studies.report import Report, write_report
from miktcli.studies.sections import requested
from miktcli.workflows.session import whole_rollouts
from miktcli.workflows.transfer import start_transfer


def names_teacher(ref: str, teacher: TeacherRef) -> bool:
    """Whether a grid's teacher reference (`name`, `name@latest`, `name@vN`) can mean this run's teacher."""
    m = REF_RE.fullmatch(ref)
    return bool(m) and m.group("name") == teacher.name and m.group("version") in (None, "latest",
                                                                                   f"v{teacher.version}")


def cell_mismatch(run: Run, pair: PairSpec, method: MethodSpec, seed: int, steps: int) -> str | None:
    """Why `run` cannot be the run of this cell (what it is instead), or None when it can be."""
    card = run.card
    refs = pair.teachers if method.uses_teachers else []
    same_teachers = len(refs) == len(card.teachers) and all(map(names_teacher, refs, card.teachers))
    if (card.kind, card.env, card.method, card.seed) != ("transfer", pair.to, method.method, seed) or not same_teachers:
        teachers = ", ".join(t.ref for t in card.teachers) or "none"
        return f"is a {card.kind} run of {card.method} on {card.env}, seed {card.seed}, teachers {teachers}"
    # a run made before budgets were rounded up to whole rollouts (9519580) recorded the budget as asked
    rounded = whole_rollouts(steps, card.config.ppo.batch_size)
    if card.total_steps not in (steps, rounded):
        whole = f" ({rounded:,} in whole rollouts of {card.config.ppo.batch_size:,})" if rounded != steps else ""
        return f"trains {card.total_steps:,} steps, the grid {steps:,}{whole}"
    if method.ppo:  # each setting the grid gives, as the model reads it, against what the run recorded
        wanted = PPOConfig.with_settings(method.ppo)
        differs = [k for k in method.ppo if getattr(wanted, k) != getattr(card.config.ppo, k)]
        if differs:
            k = differs[0]
            return f"trains with PPO {k} = {getattr(card.config.ppo, k)!r}, the grid asks {getattr(wanted, k)!r}"
    return None


STATE_WRITE_EVERY_S = 1.0  # while preparing: state.json at most this often (and at the end), not per cell
LOCK_FILE = ".lock"  # in the study folder: held by the one process driving the study (see Study.driving)


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


class Study:
    def __init__(self, grid: Grid, out_dir: Path, registry: Path):
        requested(grid)  # the report sections it asks for, checked before any cell exists
        self.grid, self.out_dir, self.registry = grid, Path(out_dir), Path(registry)
        self.state_path = self.out_dir / "state.json"
        self.lock = FileLock(self.out_dir / LOCK_FILE)
        self._driving = 0  # depth of `driving()` blocks: the lock is kept until the outermost one ends
        self.pins_path = self.out_dir / PINS_FILE
        self.pins: dict[str, Pin] = {}
        self.new_pins: list[tuple[str, Pin]] = []  # (grid reference, pin) pinned by the last `prepare`
        self.cells: dict[str, str] = {}
        self._load_state()

    def _load_state(self) -> None:
        # the runs of a state.json written by mikt 0.1 are adopted under today's keys
        self.cells = compat.adopt_cells(read_state(self.state_path), (
            (cell_key(p, m, s), compat.cell_key(p.teachers, p.to, m.name, s)) for p, m, s in self.plan()))

    @contextmanager
    def driving(self) -> Iterator[Study]:
        """Drive the study: the first `prepare` inside takes the study folder's lock, and it is kept until the
        block ends, so that no second driver trains the same cells (two drivers each trained every cell, and
        state.json and results.md then named different runs). Reading the folder (`report`) needs no lock."""
        self._driving += 1
        try:
            yield self
        finally:
            self._driving -= 1
            if not self._driving:
                self.lock.release()

    def _take_lock(self) -> None:
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
        self._load_state()

    @functools.cached_property
    def _cell_of(self) -> dict[str, tuple[PairSpec, MethodSpec, int]]:
        return {cell_key(*cell): cell for cell in self.plan()}

    def _remember(self, key: str, run_id: str, write: bool = True) -> None:
        self.cells[key] = run_id
        if write:
            self._write_state()

    def _write_state(self) -> None:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        write_text_atomic(self.state_path, json.dumps(self.cells, indent=2, ensure_ascii=False))

    def plan(self) -> list[tuple[PairSpec, MethodSpec, int]]:
        """Every (pair, method, seed) of the grid; cells with the same key share one run."""
        return [(p, m, s) for p in self.grid.pairs for m in self.grid.methods for s in self.grid.seeds]

    def distinct_cells(self) -> list[tuple[PairSpec, MethodSpec, int]]:
        """One entry per run to train: the first cell of each key."""
        seen: dict[str, tuple[PairSpec, MethodSpec, int]] = {}
        for cell in self.plan():
            seen.setdefault(cell_key(*cell), cell)
        return list(seen.values())

    def check_envs(self) -> None:
        """Every target the grid names must be a known environment: a misspelt one would otherwise train
        nothing and report an empty pair as if its cells were merely unfinished."""
        for pair in self.grid.pairs:
            try:
                load_spec(pair.to)
            except MiktError as err:
                raise MiktError(f"grid '{self.grid.name}', pair {pair.name}: {err}", hint=err.hint) from err

    def teacher_refs(self) -> list[str]:
        """Every teacher reference of the grid that a cell trains with, once each, in grid order."""
        if not any(m.uses_teachers for m in self.grid.methods):
            return []
        return list(dict.fromkeys(ref for pair in self.grid.pairs for ref in pair.teachers))

    def check_teachers(self) -> None:
        """Every teacher the grid names must exist before the first cell trains."""
        for ref in self.teacher_refs():
            resolve(self.registry, ref)

    def _pin_teachers(self) -> None:
        """Each teacher reference → one version for the whole study (studies.pins): the pin of teachers.json,
        else the version the study's earliest run used (a study prepared before pins existed), else the version
        the reference means now. Checked against this registry's files before any cell is created."""
        self.pins, self.new_pins = read_pins(self.pins_path), []
        missing = [ref for ref in self.teacher_refs() if ref not in self.pins]
        used = self._versions_used(missing) if missing else {}
        for ref in missing:
            pin = used.get(ref) or pin_now(self.registry, ref)
            self.pins[ref] = pin
            self.new_pins.append((ref, pin))
        for ref in self.teacher_refs():
            check_pin(self.registry, self.pins_path, ref, self.pins[ref])
        if self.new_pins:
            write_pins(self.pins_path, self.pins)

    def _versions_used(self, refs: list[str]) -> dict[str, Pin]:
        """For each reference, the teacher the study's earliest-created run trained with, where one did."""
        used: dict[str, Pin] = {}
        for key, run_id in by_run_number(self.cells):
            cell = self._cell_of.get(key)
            if cell is None or not cell[1].uses_teachers or not (runs_dir(self.registry) / run_id).is_dir():
                continue
            try:
                teachers = open_run(self.registry, run_id).card.teachers
            except MiktError:
                continue  # run_of names what is wrong with it when the cell is reached
            for ref, teacher in zip(cell[0].teachers, teachers, strict=False):
                if ref in refs and ref not in used and names_teacher(ref, teacher):
                    used[ref] = Pin(ref=f"{teacher.name}@v{teacher.version}", sha256=teacher.sha256)
        return used

    def run_of(self, key: str) -> Run | None:
        """The run state.json names for a cell; None when it names none or the registry has no such run (the
        cell starts afresh). A run that is there but unreadable, or that is not this cell's run, is an error:
        guessing would train a cell twice or credit it with another run's results."""
        run_id = self.cells.get(key)
        if run_id is None or not (runs_dir(self.registry) / run_id / "run.json").is_file():
            return None
        run = open_run(self.registry, run_id)
        cell = self._cell_of.get(key)
        mismatch = cell_mismatch(run, *cell, self.grid.steps) if cell else None
        if mismatch:
            raise MiktError(f"{self.state_path}: cell {key} names {run_id}, but {run_id} {mismatch}",
                            hint="another run took that id (a registry restored without this study's runs?); "
                                 "remove the cell's entry from state.json to train it afresh")
        return run

    def missing_runs(self) -> list[tuple[str, str]]:
        """(cell, run id) for each cell whose state.json entry names a run this registry does not have."""
        named = ((cell_key(*cell), self.cells.get(cell_key(*cell))) for cell in self.distinct_cells())
        return [(key, run_id) for key, run_id in named
                if run_id is not None and not (runs_dir(self.registry) / run_id).exists()]

    def prepare(self, command: str, retrain_missing: bool = False) -> list[tuple[str, Run]]:
        """Check every teacher, create the run folder of every distinct cell that has none (recorded in
        state.json), and return (cell, run) for each, finished ones included. Nothing trains here.

        Runs that state.json names but the registry lacks are refused unless `retrain_missing`: the usual
        cause is the wrong registry, where retraining would re-point state.json away from the real runs."""
        self.check_envs()
        self.check_teachers()
        with self.driving():
            self._take_lock()
            return self._prepare_cells(command, retrain_missing)

    def _prepare_cells(self, command: str, retrain_missing: bool) -> list[tuple[str, Run]]:
        missing = self.missing_runs()
        if missing and not retrain_missing:
            ids = ", ".join(run_id for _, run_id in missing[:5]) + (" …" if len(missing) > 5 else "")
            raise MiktError(f"{self.state_path} names {len(missing)} run(s) that registry "
                            f"{location.describe(self.registry)} lacks: {ids}",
                            hint=f"is this the study's registry? Restore its runs (mikt study restore {self.out_dir} "
                                 "--registry REGISTRY), or pass --retrain-missing to train those cells afresh")
        self._pin_teachers()
        self._check_envs_unchanged()
        cells: list[tuple[str, Run]] = []
        # state.json is rewritten whole, so writing it per new cell made preparing N cells quadratic in N; it is
        # written every STATE_WRITE_EVERY_S and at the end, also on an error or Ctrl-C. Only a kill in between
        # leaves up to that long's runs unnamed (created, never trained: a restart prepares those cells anew).
        unwritten, written_at = False, time.monotonic()
        try:
            for pair, method, seed in self.distinct_cells():
                if self._prepare_cell(pair, method, seed, command, cells):
                    unwritten = True
                    if time.monotonic() - written_at >= STATE_WRITE_EVERY_S:
                        self._write_state()
                        unwritten, written_at = False, time.monotonic()
        finally:
            if unwritten:
                self._write_state()
        return cells

    def _check_envs_unchanged(self) -> None:
        """Every run the study has must have trained on its environment as it is now: one row of the report
        would otherwise hold cells on two bodies or rewards."""
        now: dict[str, str] = {}
        for key, run_id in self.cells.items():
            run = self.run_of(key)
            if run is None or run.card.env_fingerprint is None:
                continue
            if run.card.env not in now:
                now[run.card.env] = spec_fingerprint(load_spec(run.card.env))
            if now[run.card.env] != run.card.env_fingerprint:
                raise MiktError(f"study '{self.grid.name}', cell {key} ({run_id}): " + describe_change(
                    run.card.env, run.card.env_fingerprint, now[run.card.env], "that cell started"),
                    hint="restore the spec, or give the edited body a new name and a grid of its own")

    def _prepare_cell(self, pair: PairSpec, method: MethodSpec, seed: int, command: str,
                      cells: list[tuple[str, Run]]) -> bool:
        """Append (cell, run) to `cells`, creating the run when the cell has none; whether it created one."""
        created = False
        key = cell_key(pair, method, seed)
        run = self.run_of(key)
        if run is None:
            run = start_transfer(
                self.registry, to=pair.to, method=method.method,
                teacher_refs=[self.pins[ref].ref for ref in pair.teachers] if method.uses_teachers else [],
                steps=self.grid.steps,
                seed=seed, command=f"{command}  # cell {key}", kl_coef=method.kl_coef, options=method.options,
                compile_loss=self.grid.compile_loss, eval_episodes=self.grid.eval_episodes,
                ppo_settings=method.ppo,
            )
            self._remember(key, run.id, write=False)
            created = True
        elif (run.card.status in ("running", "interrupted") and run.card.steps_done == 0
              and not run.checkpoint_path.exists() and lock_owner(run) is None):
            # never trained, but marked running (prepared before the `created` status) or interrupted
            # (an older Ray driver marked every cell it held)
            run.save_card(status="created")
        cells.append((key, run))
        return created

    def report_finished(self, grid_file: Path) -> Report:
        """`--report-only`: the report of what has finished, refused where the folder holds no study (an empty
        report would pass for a study without results)."""
        self.check_envs()  # training checks it before any cell is created
        if not self.cells:
            why = f"{self.state_path.name} names no cell" if self.state_path.is_file() else f"no {self.state_path.name}"
            raise MiktError(f"{self.out_dir} holds no study yet ({why}): nothing to report",
                            hint=f"is --out right? Start the study with: mikt study {grid_file} --out {self.out_dir}")
        return self.report()

    def report(self) -> Report:
        """Aggregate whatever has finished into results.md, summary.json and plots (see studies.report)."""
        return write_report(self.grid, self.out_dir, self.cells, self.run_of)
