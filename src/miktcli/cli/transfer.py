"""`mikt transfer`: train a student on a target env with knowledge from teachers (or a baseline)."""

from __future__ import annotations

from functools import partial

import typer

from miktcli import limits
from miktcli.cli.common import (
    DEFAULT_REGISTRY,
    CompileOption,
    JsonOption,
    NumEnvsOption,
    PPOSettingsOption,
    RegistryOption,
    SeedOption,
    StepsOption,
    change_update_mode_on_resume,
    command_line,
    given_on_command_line,
    note_env_copy,
    note_rounding,
    parse_hidden,
    parse_ppo_settings,
    refuse_options_of_other_methods,
    refuse_options_with_resume,
    setup_torch,
)
from miktcli.cli.console import err, print_data, print_json
from miktcli.cli.method_options import flag_of, parse_method_options
from miktcli.cli.training import train_together_run, train_transfer_run
from miktcli.errors import MethodOptionError, MiktError, TeacherCountError, TeacherMismatchError

HELP = """Transfer from teachers to a new body with MIKT, or run a baseline on the same engine.

Examples:

  mikt transfer --from centipede-four --to centipede-six --steps 200000

  mikt transfer --from centipede-six --to ant --coupling-schedule constant

  mikt transfer --from centipede-four --from hopper --to centipede-eight

  mikt transfer --to centipede-eight --method vpg

  mikt transfer --from centipede-four --to centipede-eight --method mlpp

  mikt transfer --resume run7

  mikt transfer --branch run7 --at before-teacher-free --handover fold
"""


def flag_hint(error: MiktError) -> str | None:
    """The flag behind a library error, told by the error's type (library errors speak in domain terms)."""
    if isinstance(error, TeacherCountError):
        if error.given < error.minimum:
            return "add --from NAME or NAME@vN"
        if error.maximum == 0:
            return "drop --from"
        return f"give at most {error.maximum} --from"
    if isinstance(error, TeacherMismatchError):
        return {"encoder_widths": "--encoder-width must equal each teacher's state dim; leave it out to use the "
                                  "cards'",
                "hidden": "--hidden must equal the teachers' hidden sizes; leave it out to use the cards'"
                }.get(error.stated)
    if isinstance(error, MethodOptionError) and error.option:
        return f"see {flag_of(error.option)} under `mikt transfer --help`"
    return None


def start_branch(ctx: typer.Context, registry, source: str | None, at: str | None):
    from miktcli.methods import get_method
    from miktcli.registry.runs import open_run
    from miktcli.workflows.branch import branch_run

    if not (source and at):
        raise typer.BadParameter("--branch RUN and --at CHECKPOINT go together", ctx=ctx,
                                 param_hint="'--branch'" if not source else "'--at'")
    given = given_on_command_line(ctx, {p.name for p in ctx.command.params} - BRANCH_COMPATIBLE)
    if given:
        raise typer.BadParameter("cannot be combined with --branch: a branch keeps its source run's settings "
                                 "but the method options given", ctx=ctx, param_hint=f"'{given[0]}'")
    source_method = open_run(registry, source).card.method
    options = parse_method_options(ctx, source_method, get_method(source_method).options) or {}
    return branch_run(registry, source, at, options, command_line())


# what --branch may be given beside method options: the branch point, output and where the registry is
BRANCH_COMPATIBLE = {"branch", "at", "as_json", "registry", "eval_episodes", "compile_loss"}


def transfer(
    ctx: typer.Context,
    teacher: list[str] = typer.Option(None, "--from", help="Teacher NAME or NAME@vN; repeat for several teachers."),
    to: str = typer.Option(None, "--to", help="Target environment."),
    method: str = typer.Option("mikt", "--method", help="The transfer method (listed in the full help)."),
    steps: StepsOption = 2_000_000,
    seed: SeedOption = 0,
    seeds: str = typer.Option(None, "--seeds", help="Several seeds trained in one process as one batched "
                              "problem, e.g. 0-4 or 0,2,5: one run per seed, the same distribution as alone "
                              "(not the same bits; the cards say so)."),
    kl_coef: float = typer.Option(None, "--kl-coef", min=0, help="KL(pi||pi_old) weight (default: the method's)."),
    encoder_width: list[int] = typer.Option(
        None, "--encoder-width", help="Optional check: must equal each teacher's state dim (read from its card)."),
    hidden: str = typer.Option(None, "--hidden", help="Optional check: must equal the teachers' hidden sizes."),
    num_envs: NumEnvsOption = 1,
    compile_loss: CompileOption = None,
    ppo: PPOSettingsOption = None,
    eval_episodes: int = typer.Option(10, "--eval-episodes", min=1, max=limits.MAX_EPISODES,
                                      help="Episodes for the final evaluation (recorded; kept on --resume)."),
    resume: str = typer.Option(None, "--resume", help="Continue an interrupted transfer run."),
    branch: str = typer.Option(None, "--branch", help="A new run from a checkpoint RUN kept (--at), with the "
                               "method options given here changed; e.g. another --handover on the same weights."),
    at: str = typer.Option(None, "--at", help="With --branch: the kept checkpoint, e.g. before-teacher-free "
                           "(`mikt inspect RUN` lists them)."),
    as_json: JsonOption = False,
    registry: RegistryOption = DEFAULT_REGISTRY,
) -> None:
    from miktcli.methods import get_method, transfer_methods
    from miktcli.registry.runs import open_resumable
    from miktcli.workflows.together import parse_seeds, start_transfers_together, together_group
    from miktcli.workflows.transfer import start_transfer

    setup_torch()
    reg = registry
    if seeds is not None and given_on_command_line(ctx, {"seed", "resume", "branch", "at"}):
        raise typer.BadParameter("cannot be combined with --seed, --resume or --branch", ctx=ctx,
                                 param_hint="'--seeds'")
    if branch or at or resume:
        if branch or at:
            run = start_branch(ctx, reg, branch, at)
        else:
            refuse_options_with_resume(ctx)
            run = open_resumable(reg, resume, "transfer")
        change_update_mode_on_resume(run, compile_loss)
        if run.card.config.eval_episodes is not None and not given_on_command_line(ctx, {"eval_episodes"}):
            eval_episodes = run.card.config.eval_episodes  # what the run was started with, not the default
    else:
        if to is None:
            raise MiktError("give the target environment with --to ENV (or --resume RUN)")
        m = get_method(method)
        if not m.for_transfer:
            raise MiktError(f"unknown method '{method}'; known: {', '.join(transfer_methods())}")
        options = parse_method_options(ctx, method, m.options)
        if not m.encoder_per_teacher:
            refuse_options_of_other_methods(ctx, method, {"encoder_width"})
        try:
            start = partial(start_transfers_together, reg, parse_seeds(seeds)) if seeds is not None else \
                partial(start_transfer, reg, seed=seed)
            started = start(
                to=to, method=method, teacher_refs=list(teacher or []), steps=steps, command=command_line(),
                kl_coef=kl_coef, num_envs=num_envs, options=options,
                compile_loss=compile_loss, eval_episodes=eval_episodes, ppo_settings=parse_ppo_settings(ppo),
                encoder_widths=list(encoder_width) if encoder_width else None,
                hidden=parse_hidden(hidden) if hidden else None,
            )
        except MiktError as error:
            if error.hint is None:
                error.hint = flag_hint(error)
            raise
        run = started[0] if isinstance(started, list) else started
        note_rounding(steps, run.card.total_steps)
        note_env_copy(run)
    group = together_group(reg, run)
    if len(group) > 1 or run.card.seeds_together:
        report_together(group, train_together_run(group, reg, eval_episodes), as_json)
        return
    result = train_transfer_run(run, reg, eval_episodes)
    if as_json:
        print_json({"run": run.id, **result})
        return
    report_result(run, result)


def report_together(runs, results: list[dict], as_json: bool) -> None:
    if as_json:
        print_json([{"run": run.id, **result} for run, result in zip(runs, results, strict=True)])
        return
    for run, result in zip(runs, results, strict=True):
        err.print(f"{run.id} (seed {run.card.seed}):")
        report_result(run, result)


def report_result(run, result: dict) -> None:
    without = result["eval_without_teacher"]
    if "eval_with_teacher" in result:
        w = result["eval_with_teacher"]
        err.print(f"return with teacher {w['return_mean']:.1f} ± {w['return_std']:.1f}")
    err.print(f"return without teacher {without['return_mean']:.1f} ± {without['return_std']:.1f}")
    if "final_mixing" in result:
        weights = ", ".join(f"{k}={v:.3f}" for k, v in result["final_mixing_learned"].items())
        err.print(f"final student weights {weights}")
    print_data(run.id)
