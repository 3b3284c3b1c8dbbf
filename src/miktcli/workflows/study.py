"""Studies: pairs × methods × seeds on one budget, resumable, with a Markdown table and plots.

A grid file (TOML) names the pairs, methods and seeds; the study runs each cell as an ordinary transfer
run (the same code path as `mikt transfer`), remembers which run holds which cell in `state.json`, and
skips finished cells when started again. `report` aggregates whatever has finished.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from miktcli.errors import MiktError, describe_validation_error
from miktcli.registry.files import write_text_atomic
from miktcli.registry.runs import Run, open_run


class PairSpec(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True)

    teachers: list[str] = Field(alias="from", min_length=1)
    to: str
    label: str | None = None

    @property
    def name(self) -> str:
        return self.label or f"{'+'.join(t.split('@')[0] for t in self.teachers)} → {self.to}"


class MethodSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: str
    method: str = Field(pattern="^(mikt|vpg|mlpp)$")
    kl_coef: float | None = None
    mikt: dict[str, Any] = Field(default_factory=dict)

    @property
    def uses_teachers(self) -> bool:
        return self.method != "vpg"


class Grid(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: str
    steps: int = Field(gt=0)
    seeds: list[int] = Field(min_length=1)
    marks: list[int] = Field(default_factory=list, description="step marks of the results table")
    eval_episodes: int = 10
    baseline: str = Field("vpg", description="the method whose final return the others race to")
    pairs: list[PairSpec] = Field(min_length=1)
    methods: list[MethodSpec] = Field(min_length=1)

    @model_validator(mode="after")
    def _no_duplicates(self) -> Grid:
        # Two methods of one name would share cells and overwrite each other; so would two equal pairs.
        for what, keys in (("method name", [m.name for m in self.methods]),
                           ("pair", [f"{'+'.join(p.teachers)} → {p.to}" for p in self.pairs]),
                           ("seed", [str(s) for s in self.seeds])):
            dupes = sorted({k for k in keys if keys.count(k) > 1})
            if dupes:
                raise ValueError(f"duplicate {what}: {', '.join(dupes)}")
        if self.baseline not in {m.name for m in self.methods}:
            raise ValueError(f"baseline '{self.baseline}' is not one of the methods")
        return self


def load_grid(path: Path) -> Grid:
    try:
        data = tomllib.loads(Path(path).read_text())
        return Grid.model_validate(data)
    except FileNotFoundError:
        raise MiktError(f"grid file {path} not found") from None
    except tomllib.TOMLDecodeError as err:
        raise MiktError(f"{path}: not valid TOML: {err}") from err
    except ValidationError as err:
        raise MiktError(f"{path}: {describe_validation_error(err)}") from err


def cell_key(pair: PairSpec, method: MethodSpec, seed: int) -> str:
    """The run a cell needs. A method without teachers (vpg) is the same run whatever the pair, so every
    pair with that target shares it: the key leaves the teachers out ("-" in their place)."""
    source = "+".join(pair.teachers) if method.uses_teachers else "-"
    return f"{source}>{pair.to}|{method.name}|{seed}"


def legacy_cell_key(pair: PairSpec, method: MethodSpec, seed: int) -> str:
    """Keys of state.json files written by mikt 0.1, where every cell named its pair."""
    return f"{'+'.join(pair.teachers)}>{pair.to}|{method.name}|{seed}"


def first_reach(steps: np.ndarray, curve: np.ndarray, level: float) -> str:
    hit = np.nonzero(curve >= level)[0]
    return f"{int(steps[hit[0]]):,}" if len(hit) else "not reached"


def three_quarters_level(final: float) -> float:
    """"¾ of the baseline's final return", also for a final return ≤ 0, where 0.75·final would be *above*
    it: the level a quarter of |final| below final (equal to 0.75·final when final > 0)."""
    return final - 0.25 * abs(final)


def sample_std(values: np.ndarray, axis: int | None = None) -> np.ndarray | float:
    """Sample standard deviation (ddof 1); NaN for a single value, where it is undefined."""
    values = np.asarray(values, dtype=float)
    n = values.shape[axis] if axis is not None else values.size
    if n < 2:
        return np.full(np.delete(values.shape, axis), np.nan) if axis is not None else float("nan")
    return np.nanstd(values, axis=axis, ddof=1)


def mean_pm_std(values) -> str:
    values = np.asarray(values, dtype=float)
    std = sample_std(values)
    return f"{np.mean(values):.0f} ± {std:.0f}" if math.isfinite(std) else f"{np.mean(values):.0f}"


class Study:
    def __init__(self, grid: Grid, out_dir: Path, registry: Path):
        self.grid, self.out_dir, self.registry = grid, Path(out_dir), Path(registry)
        self.state_path = self.out_dir / "state.json"
        self.cells: dict[str, str] = self._read_state()
        for pair, method, seed in self.plan():  # adopt the runs of a state.json written by mikt 0.1
            key, legacy = cell_key(pair, method, seed), legacy_cell_key(pair, method, seed)
            if key != legacy and legacy in self.cells:
                run_id = self.cells.pop(legacy)
                self.cells.setdefault(key, run_id)

    def _read_state(self) -> dict[str, str]:
        if not self.state_path.exists():
            return {}
        try:
            cells = json.loads(self.state_path.read_bytes().decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as err:
            raise MiktError(f"{self.state_path}: damaged study state: {err}",
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

    def check_teachers(self) -> None:
        """Every teacher the grid names must exist before the first cell trains."""
        from miktcli.registry.teachers import resolve

        for pair in self.grid.pairs:
            if any(m.uses_teachers for m in self.grid.methods):
                for ref in pair.teachers:
                    resolve(self.registry, ref)

    def run_of(self, key: str) -> Run | None:
        run_id = self.cells.get(key)
        if run_id is None:
            return None
        try:
            return open_run(self.registry, run_id)
        except MiktError:
            return None

    def execute(self, command: str, train: Callable[[Run], Any]) -> Iterator[tuple[str, Run, str]]:
        """Run every unfinished cell; yields (cell, run, what happened). `train` trains and finishes a run."""
        from miktcli.workflows.transfer import start_transfer

        self.check_teachers()
        for pair, method, seed in self.distinct_cells():
            key = cell_key(pair, method, seed)
            run = self.run_of(key)
            if run is not None and run.card.status == "completed":
                yield key, run, "done"
                continue
            if run is None:
                run = start_transfer(
                    self.registry, to=pair.to, method=method.method,
                    teacher_refs=pair.teachers if method.uses_teachers else [], steps=self.grid.steps,
                    seed=seed, command=f"{command}  # cell {key}", kl_coef=method.kl_coef, mikt_options=method.mikt,
                )
                self._remember(key, run.id)
                yield key, run, "start"
            else:
                yield key, run, "resume"
            train(run)
            yield key, open_run(self.registry, run.id), "finished"

    # --- the report ---------------------------------------------------------------------------------
    def _curves(self, pair: PairSpec, method: MethodSpec) -> tuple[list[Run], np.ndarray, np.ndarray]:
        """Completed runs of a cell group and their return curves on the common iteration grid."""
        runs, curves = [], []
        for seed in self.grid.seeds:
            run = self.run_of(cell_key(pair, method, seed))
            if run is None or run.card.status != "completed":
                continue
            rows = run.read_metrics()
            runs.append(run)
            curves.append([(r["steps"], np.nan if r["return_mean"] is None else r["return_mean"]) for r in rows])
        if not curves:
            return [], np.zeros(0), np.zeros((0, 0))
        length = min(len(c) for c in curves)
        steps = np.array([s for s, _ in curves[0][:length]])
        return runs, steps, np.array([[v for _, v in c[:length]] for c in curves])

    def report(self) -> Path:
        from miktcli.plots import png_plot

        self.out_dir.mkdir(parents=True, exist_ok=True)
        g = self.grid
        lines = [f"# Study `{g.name}`", "",
                 f"{g.steps:,} steps per run, seeds {g.seeds}, {g.eval_episodes} evaluation episodes per run. "
                 "Returns are the mean training-episode return over the last 100 episodes at each mark (the last "
                 "iteration at or before it: the column names that step), then mean ± sample std (ddof 1) over "
                 "the n completed seeds; *mean over training* averages that curve over the whole run (area under "
                 "the curve per step); *final eval* is the teacher-free student, deterministic, on fresh seeds. "
                 f"*¾ of {g.baseline} final* is the level a quarter of |final| below the baseline's final return "
                 "(0.75 × final when it is positive).",
                 ""]
        summary: dict[str, Any] = {}
        for pair in g.pairs:
            data = {m.name: self._curves(pair, m) for m in g.methods}
            base_runs, base_steps, base_curves = data[g.baseline]
            base_final = float(np.nanmean(base_curves[:, -1])) if len(base_runs) else None
            marks = [m for m in g.marks if m <= g.steps] or [g.steps]
            any_steps = next((steps for runs, steps, _ in data.values() if runs), None)
            mark_index = {}
            for mark in marks:
                i = int(np.searchsorted(any_steps, mark, side="right")) - 1 if any_steps is not None else -1
                mark_index[mark] = i
            mark_labels = [f"{int(any_steps[i]):,}" if i >= 0 else f"{m:,}" for m, i in mark_index.items()]
            header = ["method", "n", *mark_labels, "mean over training",
                      "final eval (no teacher)", f"steps to {g.baseline} final", f"steps to ¾ of {g.baseline} final",
                      "final student weights p (π / V)"]
            lines += [f"## {pair.name}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
            series, bands, weight_series = {}, {}, {}
            summary[pair.name] = {}
            for method in g.methods:
                runs, steps, curves = data[method.name]
                if not runs:
                    lines.append(f"| {method.name} | 0 | " + " | ".join("—" for _ in header[2:]) + " |")
                    continue
                mean = np.nanmean(curves, 0)
                std = sample_std(curves, axis=0)
                cells = ["—" if i < 0 or i >= len(mean) or math.isnan(mean[i]) else mean_pm_std(curves[:, i])
                         for i in mark_index.values()]
                evals = [r.card.result["eval_without_teacher"]["return_mean"] for r in runs]
                reach = reach_75 = "—"
                if base_final is not None:
                    reach, reach_75 = (first_reach(steps, mean, level)
                                       for level in (base_final, three_quarters_level(base_final)))
                weights = "—"
                mixing = [r.card.result.get("final_mixing_learned") for r in runs]
                if all(mixing):
                    keys = sorted(mixing[0])
                    avg = {k: float(np.mean([m[k] for m in mixing])) for k in keys}
                    pi = "/".join(f"{avg[k]:.2f}" for k in keys if k.startswith("p_pi"))
                    vf = "/".join(f"{avg[k]:.2f}" for k in keys if k.startswith("p_vf"))
                    weights = f"{pi} · {vf}"
                    rows = [r.read_metrics() for r in runs]
                    n = min(len(r) for r in rows)
                    for k in keys:
                        weight_series[f"{method.name} {k}"] = [
                            (rows[0][i]["steps"], float(np.mean([r[i][k] for r in rows]))) for i in range(n)]
                # Area under the curve per step: how much return the whole run collected, jump-start included.
                auc = np.nanmean(curves, axis=1)
                lines.append(f"| {method.name} | {len(runs)} | " + " | ".join(cells)
                             + f" | {mean_pm_std(auc)} | {mean_pm_std(evals)} | {reach} | {reach_75} | {weights} |")
                series[method.name] = list(zip(steps.tolist(), mean.tolist(), strict=True))
                band = np.nan_to_num(std)  # one seed: no band
                bands[method.name] = list(zip(steps.tolist(), (mean - band).tolist(), (mean + band).tolist(),
                                              strict=True))
                summary[pair.name][method.name] = {
                    "runs": [r.id for r in runs], "n": len(runs),
                    "final_eval_mean": float(np.mean(evals)), "final_eval_std": _json_number(sample_std(evals)),
                    "final_train_mean": float(mean[-1]), "final_train_std": _json_number(std[-1]),
                    "marks": {str(int(steps[i])): {"mean": float(mean[i]), "std": _json_number(std[i])}
                              for i in mark_index.values() if 0 <= i < len(mean)},
                    "mean_over_training": float(np.mean(auc)), "mean_over_training_std": _json_number(sample_std(auc)),
                    "steps_to_baseline_final": reach, "steps_to_three_quarters_of_baseline_final": reach_75,
                }
            slug = "".join(c if c.isalnum() else "-" for c in pair.name.replace(" → ", "-to-")).strip("-")
            if series:
                png_plot(series, self.out_dir / f"curves-{slug}.png", pair.name, "mean episode return", bands)
                lines += ["", f"![learning curves]({f'curves-{slug}.png'})"]
            if weight_series:
                png_plot(weight_series, self.out_dir / f"weights-{slug}.png", f"{pair.name}: student weights",
                         "p (student)")
                lines += ["", f"![student weights]({f'weights-{slug}.png'})"]
            lines.append("")
        lines += ["## Runs", "", "Cells without teachers (`-`) are one run shared by every pair with that target.", "",
                  "| cell (teachers > target) | method | seed | run |", "|---|---|---|---|"]
        lines += [f"| {' | '.join(k.split('|'))} | {v} |" for k, v in self.cells.items()]
        path = self.out_dir / "results.md"
        write_text_atomic(path, "\n".join(lines) + "\n")
        write_text_atomic(self.out_dir / "summary.json", json.dumps(summary, indent=2, ensure_ascii=False))
        return path


def _json_number(value: float) -> float | None:
    return float(value) if math.isfinite(float(value)) else None
