"""`mikt runs`: list the runs in the registry."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from miktcli.cli.common import registry_option, resolve_registry
from miktcli.cli.console import err, out, print_json


def runs(
    as_json: bool = typer.Option(False, "--json", help="Print the run cards as JSON."),
    registry: Path = registry_option(),
) -> None:
    """List runs (teacher training and transfers) with status and results."""
    from miktcli.runs import list_runs

    reg = resolve_registry(registry)
    found = list_runs(reg)
    if as_json:
        print_json([r.card.model_dump(mode="json") for r in found])
        return
    if not found:
        err.print(f"no runs in {reg}")
        return
    table = Table("run", "kind", "method", "from", "env", "status", "steps", "result", "created")
    for r in found:
        c = r.card
        res = c.result
        if "eval_without_teacher" in res:
            summary = f"{res['eval_without_teacher']['return_mean']:.1f}"
        elif res.get("final_return") is not None:
            summary = f"{res['final_return']:.1f}"
        else:
            summary = "—"
        table.add_row(c.run_id, c.kind, c.method, ", ".join(f"{t.name}@v{t.version}" for t in c.teachers) or "—",
                      c.env, c.status, f"{c.steps_done:,}/{c.total_steps:,}", summary, str(c.created)[:19])
    out.print(table)
