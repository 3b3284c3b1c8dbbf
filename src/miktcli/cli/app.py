"""The `mikt` command: groups of nouns plus the hottest verbs at the top level."""

from __future__ import annotations

import os
import signal
import sys

import typer
from typer.core import TyperGroup
from typer.exceptions import TyperException

from miktcli import __version__
from miktcli.cli import envs as envs_cmd
from miktcli.cli import eval as eval_cmd
from miktcli.cli import inspect as inspect_cmd
from miktcli.cli import runs as runs_cmd
from miktcli.cli import study as study_cmd
from miktcli.cli import study_carry, study_examples
from miktcli.cli import teacher as teacher_cmd
from miktcli.cli import transfer as transfer_cmd
from miktcli.cli.console import debug_enabled, err, print_error
from miktcli.cli.method_options import PASS_UNKNOWN_FLAGS, MethodOptionsCommand
from miktcli.errors import MiktError, describe_os_error

EXIT_BROKEN_PIPE = 1  # what rich's Console gives for a closed pipe under a table: one status for both


def _quiet_stdout() -> None:
    """Point stdout at /dev/null, so the interpreter's final flush into the closed pipe says nothing either."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)


class MiktGroup(TyperGroup):
    """Turns known errors into one line on stderr and exit 1; tracebacks only with MIKT_DEBUG=1."""

    def invoke(self, ctx):
        try:
            result = super().invoke(ctx)
            sys.stdout.flush()  # here, so a closed pipe is met inside this handler and not at exit
            return result
        except MiktError as error:
            if debug_enabled():
                raise
            print_error(error, error.hint)
            raise typer.Exit(1) from None
        except BrokenPipeError:  # `mikt runs --json | head -n 1`: the reader has all it wanted
            _quiet_stdout()
            raise typer.Exit(EXIT_BROKEN_PIPE) from None
        except OSError as error:  # permissions, a full disk, a file where a folder belongs: not a bug
            if debug_enabled():
                raise
            known = describe_os_error(error)
            print_error(known, known.hint)
            raise typer.Exit(1) from None
        except KeyboardInterrupt:
            err.print("Interrupted.")
            raise typer.Exit(130) from None
        except (typer.Exit, typer.Abort, TyperException):
            raise  # usage errors (BadParameter, a TyperException) are printed by typer itself, exit 2
        except Exception as error:  # an unexpected bug: still one line unless debugging
            if debug_enabled():
                raise
            print_error(f"internal error: {type(error).__name__}: {error}",
                        "run again with MIKT_DEBUG=1 for the traceback, and please report it.")
            raise typer.Exit(1) from None


app = typer.Typer(
    cls=MiktGroup,
    name="mikt",
    help="Cross-morphology knowledge transfer for RL (MIKT, UAI 2020) on a fast CPU PPO engine.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
    add_completion=True,  # --install-completion, --show-completion (bash, zsh, fish, PowerShell)
)


def _version(value: bool) -> None:
    if value:
        print(f"mikt {__version__}")
        raise typer.Exit()


@app.callback()
def root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version."),
) -> None:
    """Train teachers, transfer them to new bodies, inspect and evaluate the results."""


app.add_typer(envs_cmd.app, name="envs")
app.add_typer(teacher_cmd.app, name="teacher")
app.command("transfer", help=transfer_cmd.HELP, no_args_is_help=True, cls=MethodOptionsCommand,
            context_settings=PASS_UNKNOWN_FLAGS)(transfer_cmd.transfer)
app.command("eval", help=eval_cmd.HELP)(eval_cmd.eval_command)
app.command("inspect", help=inspect_cmd.HELP)(inspect_cmd.inspect)
app.command("runs")(runs_cmd.runs)
study_cmd.app.command("examples")(study_examples.examples)
study_cmd.app.command("snapshot")(study_carry.snapshot)
study_cmd.app.command("restore")(study_carry.restore)
app.add_typer(study_cmd.app, name="study")


def _stop_on_sigterm(signum, frame) -> None:
    raise KeyboardInterrupt  # same clean stop as Ctrl-C: the run is marked interrupted, checkpoints stay whole


def main() -> None:
    signal.signal(signal.SIGTERM, _stop_on_sigterm)
    try:
        app()
    except MiktError as error:  # raised while building the command tree, outside MiktGroup.invoke
        print_error(error, error.hint)
        sys.exit(1)
