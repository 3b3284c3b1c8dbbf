"""A study's plan and state: pairs × methods × seeds on one budget, resumable.

A grid file (TOML) names the pairs, methods and seeds; the study prepares each cell as an ordinary transfer
run (the same code path as `mikt transfer`), remembers which run holds which cell in `state.json`, and
skips finished cells when started again. An executor (studies.serial, studies.ray_executor) trains the
prepared cells; `report` aggregates whatever has finished.
"""

from __future__ import annotations

import functools
import json
import os
from pathlib import Path

from miktcli import compat
from miktcli.envs.spec import load_spec
from miktcli.errors import MiktError
from miktcli.registry.cards import TeacherRef
from miktcli.registry.files import write_text_atomic
from miktcli.registry.runs import Run, lock_owner, open_run, runs_dir
from miktcli.registry.teachers import REF_RE, resolve
from miktcli.studies.grid import Grid, MethodSpec, PairSpec, cell_key
from miktcli.studies.report import Report, write_report
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
    if card.total_steps != whole_rollouts(steps, card.config.ppo.batch_size):
        return f"trains {card.total_steps:,} steps, the grid {steps:,}"
    return None


class Study:
    def __init__(self, grid: Grid, out_dir: Path, registry: Path):
        self.grid, self.out_dir, self.registry = grid, Path(out_dir), Path(registry)
        self.state_path = self.out_dir / "state.json"
        self.cells: dict[str, str] = compat.adopt_cells(self._read_state(), (
            (cell_key(p, m, s), compat.cell_key(p.teachers, p.to, m.name, s)) for p, m, s in self.plan()))

    @functools.cached_property
    def _cell_of(self) -> dict[str, tuple[PairSpec, MethodSpec, int]]:
        return {cell_key(*cell): cell for cell in self.plan()}

    def _read_state(self) -> dict[str, str]:
        if not self.state_path.exists():
            return {}
        try:
            cells = json.loads(self.state_path.read_bytes().decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as err:
            raise MiktError(f"{self.state_path}: damaged study state: {type(err).__name__}: {err}",
                            hint="restore it, or move it away to start the study afresh") from err
        if not (isinstance(cells, dict) and all(isinstance(k, str) and isinstance(v, str) for k, v in cells.items())):
            raise MiktError(f"{self.state_path}: damaged study state: expected an object of cell → run id",
                            hint="restore it, or move it away to start the study afresh")
        return cells

    def _remember(self, key: str, run_id: str) -> None:
        self.cells[key] = run_id
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

    def check_teachers(self) -> None:
        """Every teacher the grid names must exist before the first cell trains."""
        for pair in self.grid.pairs:
            if any(m.uses_teachers for m in self.grid.methods):
                for ref in pair.teachers:
                    resolve(self.registry, ref)

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
        self.out_dir.mkdir(parents=True, exist_ok=True)
        if not os.access(self.out_dir, os.W_OK):  # before any run exists: else each try leaves one behind
            raise MiktError(f"cannot write the study's results to {self.out_dir} (read-only or no permission)",
                            hint="choose another --out")
        missing = self.missing_runs()
        if missing and not retrain_missing:
            ids = ", ".join(run_id for _, run_id in missing[:5]) + (" …" if len(missing) > 5 else "")
            raise MiktError(f"{self.state_path} names {len(missing)} run(s) that {self.registry} lacks: {ids}",
                            hint="is this the study's registry? Restore its runs (benchmarks/snapshot_study.py "
                                 "--restore), or pass --retrain-missing to train those cells afresh")
        cells = []
        for pair, method, seed in self.distinct_cells():
            key = cell_key(pair, method, seed)
            run = self.run_of(key)
            if run is None:
                run = start_transfer(
                    self.registry, to=pair.to, method=method.method,
                    teacher_refs=pair.teachers if method.uses_teachers else [], steps=self.grid.steps,
                    seed=seed, command=f"{command}  # cell {key}", kl_coef=method.kl_coef, options=method.options,
                    compile_loss=self.grid.compile_loss, eval_episodes=self.grid.eval_episodes,
                )
                self._remember(key, run.id)
            elif (run.card.status in ("running", "interrupted") and run.card.steps_done == 0
                  and not run.checkpoint_path.exists() and lock_owner(run) is None):
                # never trained, but marked running (prepared before the `created` status) or interrupted
                # (an older Ray driver marked every cell it held)
                run.save_card(status="created")
            cells.append((key, run))
        return cells

    def report(self) -> Report:
        """Aggregate whatever has finished into results.md, summary.json and plots (see studies.report)."""
        return write_report(self.grid, self.out_dir, self.cells, self.run_of)
