"""A card (teacher or run) as a two-column table on stdout: shared by `mikt teacher show` and `mikt inspect`."""

from __future__ import annotations

from rich.table import Table

from miktcli.cli.console import out


def render_card(data: dict) -> None:
    from miktcli.registry.cards import CodeSegment, describe_code_history

    table = Table(show_header=False, box=None)
    for key, value in data.items():
        if key == "code_history":
            if data.get("imported_from"):  # trained elsewhere: its import record says where
                continue
            trained = data.get("steps_done", data.get("steps", 0)) > 0  # run cards / teacher cards
            value = describe_code_history([CodeSegment.model_validate(s) for s in value], data["code_version"],
                                          trained=trained)
        elif isinstance(value, dict):
            value = ", ".join(f"{k}={v}" for k, v in value.items())
        table.add_row(key, str(value))
    out.print(table)
