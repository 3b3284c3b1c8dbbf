"""`mikt runs`: list the runs in the registry."""

from __future__ import annotations

from rich.table import Table

from miktcli.cli.common import DEFAULT_REGISTRY, JsonOption, RegistryOption
from miktcli.cli.console import err, out, print_json


def _result_summary(result: dict) -> str:
    """The teacher-free eval return, else the final training return; a NaN stored as null reads as '—'."""
    evaluated = result.get("eval_without_teacher")
    value = evaluated.get("return_mean") if isinstance(evaluated, dict) else result.get("final_return")
    return f"{value:.1f}" if isinstance(value, int | float) else "—"


def runs(
    as_json: JsonOption = False,
    registry: RegistryOption = DEFAULT_REGISTRY,
) -> None:
    """List runs (teacher training and transfers) with status and results."""
    from miktcli.registry import location
    from miktcli.registry.runs import list_runs

    reg = registry
    found, damaged = list_runs(reg)
    if as_json:
        # `status` is the live one: `stale` where the card says running but no process holds the run's lock.
        print_json([{**r.card.model_dump(mode="json"), "status": r.status} for r in found]
                   + [{"run_id": run_id, "error": str(problem)} for run_id, problem in damaged])
        return
    if not found and not damaged:
        err.print(f"no runs yet in registry {location.describe(reg)}")
        err.print(f"Hint: {location.HINT}")
        return
    table = Table("run", "kind", "method", "from", "env", "status", "steps", "result", "created")
    for r in found:
        c = r.card
        summary = _result_summary(c.result)
        table.add_row(c.run_id, c.kind, c.method, ", ".join(t.ref for t in c.teachers) or "—",
                      c.env, r.status, f"{c.steps_done:,}/{c.total_steps:,}", summary, str(c.created)[:19])
    for run_id, problem in damaged:
        table.add_row(run_id, "", "", "", "", "damaged", "", str(problem), "")
    out.print(table)
    if any(r.status == "stale" for r in found):
        err.print("stale: the run's process is gone (killed or crashed); its last checkpoint is intact and "
                  "`--resume RUN` continues it.")
