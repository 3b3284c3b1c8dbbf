"""Options and helpers shared by the command modules."""

from __future__ import annotations

import os
import shlex
import sys
from pathlib import Path
from typing import Annotated

import typer

from miktcli import limits
from miktcli.errors import MiktError

# Options shared by several commands, declared once.
RegistryOption = Annotated[Path, typer.Option(
    "--registry", envvar="MIKT_REGISTRY", show_default=False,
    help="Registry folder (default: $MIKT_REGISTRY or ./registry).")]
JsonOption = Annotated[bool, typer.Option("--json", help="Print as JSON (data on stdout).")]
SeedOption = Annotated[int, typer.Option("--seed", min=0, max=2**32 - 1, help="Random seed.")]
StepsOption = Annotated[int, typer.Option("--steps", min=1, max=limits.MAX_STEPS,
                                          help="Environment steps (the paper: 2M).")]
NumEnvsOption = Annotated[int, typer.Option("--num-envs", min=1, max=limits.MAX_NUM_ENVS,
                                            help="Synchronous environments (the paper: 1).")]
CompileOption = Annotated[bool | None, typer.Option(
    "--compile/--no-compile", show_default=False,
    help="Compile the PPO update with torch.compile (the same maths to float rounding; faster updates, ~20-30 s "
    "to compile; needs a C++ compiler). Default: auto, on from 500,000 steps when a compiler is found. The "
    "choice and its reason are recorded in the run.")]
PPOSettingsOption = Annotated[list[str] | None, typer.Option(
    "--ppo", metavar="KEY=VALUE", show_default=False,
    help="A PPO setting, repeatable (e.g. --ppo clip_range=0.1 --ppo bootstrap_truncation=false); recorded in "
    "the run. `mikt transfer --help` lists the settings.")]
DEFAULT_REGISTRY = Path("registry")


def parse_ppo_settings(items: list[str] | None) -> dict[str, str]:
    """`--ppo KEY=VALUE` items as {key: value as typed}; PPOConfig validates and converts them."""
    settings: dict[str, str] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise typer.BadParameter(f"expected KEY=VALUE, got {item!r}", param_hint="'--ppo'")
        settings[key.strip()] = value.strip()
    return settings


def ppo_settings_help() -> str:
    from miktcli.engine.ppo import PPOConfig

    fields = PPOConfig.model_fields
    return "PPO settings (--ppo KEY=VALUE; in a study grid, a method's ppo = { KEY = VALUE }):\n\n" + "\n\n".join(
        f"{k} (default {fields[k].default!r})" + (f": {fields[k].description}" if fields[k].description else "")
        for k in PPOConfig.settable())


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


# What a resumed run may still be told: how to report and where its registry is. Everything else (method,
# teachers, steps, seed, envs, options) is the run card's, so a flag for it would be silently ignored.
RESUME_COMPATIBLE = {"resume", "as_json", "registry", "eval_episodes", "compile_loss"}


def change_update_mode_on_resume(run, compile_loss: bool | None) -> None:
    """`--resume RUN --compile/--no-compile`: the update's mode may change mid-run (the same maths to float
    rounding); the card's compile_reason records from which step."""
    from miktcli.engine.compile_choice import change_on_resume

    ppo = run.card.config.ppo
    if compile_loss is not None and ppo.gradients == "by-hand":
        raise MiktError(f"{run.id} computes its gradient by hand (gradients=by-hand): --compile and --no-compile "
                        "choose between autograd's paths, and a run keeps its gradient path on resume",
                        hint=f"resume without {'--compile' if compile_loss else '--no-compile'}")
    if compile_loss is None or compile_loss == ppo.compile_loss:
        return
    reason = change_on_resume(ppo.compile_reason, compile_loss, run.card.steps_done)
    config = run.card.config.model_copy(update={"ppo": ppo.model_copy(update={"compile_loss": compile_loss,
                                                                              "compile_reason": reason})})
    run.save_card(config=config)


def given_on_command_line(ctx: typer.Context, names: set[str] | None = None) -> list[str]:
    """The flags (or argument names) of the parameters in `names` (all when None) that the user gave."""
    given = []
    for param in ctx.command.params:
        if names is not None and param.name not in names:
            continue
        source = ctx.get_parameter_source(param.name)
        # compared by name: typer ships its own copy of click, whose enum is not click's
        if source is not None and source.name not in ("DEFAULT", "DEFAULT_MAP"):
            given.append(param.opts[0] if param.param_type_name == "option" else param.name.upper())
    return given


def refuse_options_of_other_methods(ctx: typer.Context, method: str, names: set[str]) -> None:
    """A usage error (exit 2) for an option of another method, which this one would silently ignore."""
    given = given_on_command_line(ctx, names)
    if given:
        raise typer.BadParameter(f"does not apply to --method {method}, which has no such option", ctx=ctx,
                                 param_hint=f"'{given[0]}'")


def refuse_options_with_resume(ctx: typer.Context) -> None:
    """A usage error (exit 2) naming the first option or argument given on the command line beside --resume."""
    given = given_on_command_line(ctx, {p.name for p in ctx.command.params} - RESUME_COMPATIBLE) + ctx.args
    if given:
        raise typer.BadParameter("cannot be combined with --resume: a resumed run keeps the settings its card "
                                 "records", ctx=ctx, param_hint=f"'{given[0]}'")


def parse_hidden(text: str) -> list[int]:
    try:
        sizes = [int(s) for s in text.split(",")]  # an empty piece ("64,,64") is a typo, not a layer to skip
    except ValueError:
        raise MiktError(f"--hidden '{text}': expected comma-separated integers such as 64,64") from None
    if not sizes or any(s <= 0 for s in sizes):
        raise MiktError(f"--hidden '{text}': expected positive layer sizes such as 64,64")
    return sizes


def note_env_copy(run) -> None:
    """Say on stderr when a new run cannot carry its environment (registry/carried.py): `eval` and `--resume`
    then need its spec in a spec folder, as before."""
    from miktcli.cli.console import err
    from miktcli.registry.carried import why_no_copy

    why = why_no_copy(run.path, run.card.env)
    if why:
        err.print(f"note: {run.id} does not carry environment '{run.card.env}' ({why}): eval and --resume from "
                  "another folder need its spec in a spec folder")


def note_teacher_env(card) -> None:
    """Say on stderr when a published teacher does not carry its environment."""
    from miktcli.cli.console import err

    if not card.env_files:
        err.print(f"note: {card.ref} does not carry environment '{card.env}': eval and transfers to it from "
                  "another folder need its spec in a spec folder")


def note_compile(run) -> None:
    """Say on stderr which update runs (by hand, compiled or eager) and why, as the card records it."""
    from miktcli.cli.console import err

    ppo = run.card.config.ppo
    if ppo.gradients == "by-hand":
        err.print("update: by hand (gradients=by-hand; --ppo gradients=autograd for autograd's)")
    elif ppo.compile_reason:
        err.print(f"update: {'compiled' if ppo.compile_loss else 'eager'} ({ppo.compile_reason})")
