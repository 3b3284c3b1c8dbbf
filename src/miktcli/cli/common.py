"""Options and helpers shared by the command modules."""

from __future__ import annotations

import os
import shlex
import sys
from pathlib import Path

import typer

REGISTRY_HELP = "Registry folder (default: $MIKT_REGISTRY or ./registry)."


def registry_option() -> Path | None:
    return typer.Option(None, "--registry", help=REGISTRY_HELP, show_default=False)


def resolve_registry(path: Path | None) -> Path:
    if path is not None:
        return path
    return Path(os.environ.get("MIKT_REGISTRY", "registry"))


def command_line() -> str:
    return shlex.join(["mikt", *sys.argv[1:]])


def note_rounding(asked: int, planned: int) -> None:
    if planned != asked:
        from miktcli.cli.console import err

        err.print(f"--steps {asked:,} is not a whole number of rollouts: training {planned:,} steps")


def setup_torch() -> None:
    import torch

    # One process, one thread: measured faster than two threads on these small networks.
    torch.set_num_threads(int(os.environ.get("MIKT_THREADS", "1")))
