"""`mikt study examples`: the grids shipped with mikt (miktcli.examples), listed or copied out to edit."""

from __future__ import annotations

import typer
from rich.table import Table

from miktcli.cli.common import JsonOption
from miktcli.cli.console import err, out, print_data, print_json


def examples(
    copy: str = typer.Option(None, "--copy", metavar="NAME", help="Copy this example out to edit it (see --to)."),
    to: str = typer.Option(None, "--to", metavar="PATH", help="With --copy: the file, or a folder for NAME.toml "
                           "(default: ./NAME.toml; an existing file is never overwritten)."),
    as_json: JsonOption = False,
) -> None:
    """List the example grids shipped with mikt, or copy one out to edit (--copy NAME).

    Run one with `mikt study --example NAME`; an edited copy with `mikt study NAME.toml`."""
    from miktcli.examples import copy_example
    from miktcli.examples import examples as shipped

    if copy is None:
        if to is not None:
            raise typer.BadParameter("applies only with --copy NAME", param_hint="'--to'")
        found = shipped()
        if as_json:
            print_json([{"name": e.name, "description": e.description, "path": str(e.path)} for e in found])
            return
        table = Table("example", "what it runs")
        for e in found:
            table.add_row(e.name, e.description)
        out.print(table)
        err.print("run one with: mikt study --example NAME; copy one out to edit with: mikt study examples "
                  "--copy NAME")
        return
    written = copy_example(copy, to)
    if as_json:
        print_json({"name": copy, "path": str(written)})
        return
    err.print(f"copied example '{copy}' to {written}; run it with: mikt study {written}")
    print_data(written)
