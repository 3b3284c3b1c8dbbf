"""The study's TensorBoard tree: every started cell's metrics as an event file under PAIR/METHOD/seedN."""

from __future__ import annotations

from pathlib import Path

from miktcli.registry.files import write_bytes_atomic
from miktcli.registry.tensorboard import EVENTS_FILE, event_records
from miktcli.studies.grid import Grid, cell_key, file_slug
from miktcli.studies.summary import RunOf


def write_tensorboard_tree(grid: Grid, folder: Path, run_of: RunOf) -> None:
    """One event file per started cell, under PAIR/METHOD/seedN, made from the run's metrics.jsonl (the
    source of truth), so TensorBoard groups and compares the study's runs. A shared run appears under every
    pair it serves."""
    for pair in grid.pairs:
        for method in grid.methods:
            for seed in grid.seeds_of(pair, method):
                run = run_of(cell_key(pair, method, seed))
                if run is None:
                    continue
                target = folder / file_slug(pair.name) / file_slug(method.name) / f"seed{seed}" / EVENTS_FILE
                write_bytes_atomic(target, event_records(run.read_metrics(), wall_time=0.0))
