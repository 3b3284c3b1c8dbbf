"""A study's plan and state: pairs × methods × seeds on one budget, resumable.

A grid file (TOML) names the pairs, methods and seeds; the study prepares each cell as an ordinary transfer
run (the same code path as `mikt transfer`), remembers which run holds which cell in `state.json`, and
skips finished cells when started again. An executor (studies.serial, studies.ray_executor) trains the
prepared cells; `report` aggregates whatever has finished.
"""

from __future__ import annotations

import functools
import time
from pathlib import Path

from miktcli import compat
from miktcli.engine.ppo import PPOConfig
from miktcli.envs.fingerprint import describe_change, spec_fingerprint
from miktcli.envs.spec import load_spec
from miktcli.errors import MiktError
from miktcli.registry import location
from miktcli.registry.cards import TeacherRef
from miktcli.registry.runs import Run, lock_owner, open_run, runs_dir
from miktcli.registry.teachers import REF_RE, resolve
from miktcli.studies.grid import Grid, MethodSpec, PairSpec, cell_key
from miktcli.studies.pins import Pin, TeacherPins
from miktcli.studies.report import Report, write_report
from miktcli.studies.sections import requested
from miktcli.studies.state import StudyState, by_run_number
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


class Study:
    """A grid's cells on one registry: its folder's state and lock (studies.state), its teacher pins
    (studies.pins), and the preparation of each cell as an ordinary transfer run."""

    def __init__(self, grid: Grid, out_dir: Path, registry: Path):
        requested(grid)  # the report sections it asks for, checked before any cell exists
        self.grid, self.out_dir, self.registry = grid, Path(out_dir), Path(registry)
        # the runs of a state.json written by mikt 0.1 are adopted under today's keys
        self.state = StudyState(self.out_dir, lambda cells: compat.adopt_cells(cells, (
            (cell_key(p, m, s), compat.cell_key(p.teachers, p.to, m.name, s)) for p, m, s in self.plan())))
        self.teacher_pins = TeacherPins(self.out_dir)

    @property
    def cells(self) -> dict[str, str]:
        return self.state.cells

    def driving(self):
        """The study folder's driver lock, kept until the block ends (StudyState.driving)."""
        return self.state.driving()

    @functools.cached_property
    def _cell_of(self) -> dict[str, tuple[PairSpec, MethodSpec, int]]:
        return {cell_key(*cell): cell for cell in self.plan()}

    def plan(self) -> list[tuple[PairSpec, MethodSpec, int]]:
        """Every (pair, method, seed) of the grid; cells with the same key share one run."""
        return [(p, m, s) for p in self.grid.pairs for m in self.grid.methods for s in self.grid.seeds_of(p, m)]

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
            raise MiktError(f"{self.state.path}: cell {key} names {run_id}, but {run_id} {mismatch}",
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
            self.state.take_lock()
            return self._prepare_cells(command, retrain_missing)

    def _prepare_cells(self, command: str, retrain_missing: bool) -> list[tuple[str, Run]]:
        missing = self.missing_runs()
        if missing and not retrain_missing:
            ids = ", ".join(run_id for _, run_id in missing[:5]) + (" …" if len(missing) > 5 else "")
            raise MiktError(f"{self.state.path} names {len(missing)} run(s) that registry "
                            f"{location.describe(self.registry)} lacks: {ids}",
                            hint=f"is this the study's registry? Restore its runs (mikt study restore {self.out_dir} "
                                 "--registry REGISTRY), or pass --retrain-missing to train those cells afresh")
        self.teacher_pins.pin(self.registry, self.teacher_refs(), self._versions_used)
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
                        self.state.write()
                        unwritten, written_at = False, time.monotonic()
        finally:
            if unwritten:
                self.state.write()
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
                teacher_refs=[self.teacher_pins.ref(ref) for ref in pair.teachers] if method.uses_teachers else [],
                steps=self.grid.steps,
                seed=seed, command=f"{command}  # cell {key}", kl_coef=method.kl_coef, options=method.options,
                compile_loss=self.grid.compile_loss, eval_episodes=self.grid.eval_episodes,
                ppo_settings=method.ppo, together=self.grid.seeds_together,
            )
            self.state.remember(key, run.id, write=False)
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
            why = f"{self.state.path.name} names no cell" if self.state.path.is_file() else f"no {self.state.path.name}"
            raise MiktError(f"{self.out_dir} holds no study yet ({why}): nothing to report",
                            hint=f"is --out right? Start the study with: mikt study {grid_file} --out {self.out_dir}")
        return self.report()

    def report(self) -> Report:
        """Aggregate whatever has finished into results.md, summary.json and plots (see studies.report)."""
        return write_report(self.grid, self.out_dir, self.cells, self.run_of)
