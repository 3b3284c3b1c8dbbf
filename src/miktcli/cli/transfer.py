"""`mikt transfer`: train a student on a target env with knowledge from teachers (or a baseline)."""

from __future__ import annotations

from pathlib import Path

import typer

from miktcli.cli.common import (
    DEFAULT_REGISTRY,
    CompileOption,
    JsonOption,
    NumEnvsOption,
    RegistryOption,
    SeedOption,
    StepsOption,
    command_line,
    note_compile,
    note_rounding,
    refuse_options_of_other_methods,
    refuse_options_with_resume,
    setup_torch,
)
from miktcli.cli.console import err, print_data, print_json
from miktcli.cli.progress import training_progress
from miktcli.errors import MiktError

HELP = """Transfer from teachers to a new body with MIKT, or run a baseline on the same engine.

Examples:

  mikt transfer --from centipede-four --to centipede-six --steps 200000

  mikt transfer --from centipede-six --to ant --coupling-schedule constant

  mikt transfer --from centipede-four --from hopper --to centipede-eight

  mikt transfer --to centipede-eight --method vpg

  mikt transfer --from centipede-four --to centipede-eight --method mlpp

  mikt transfer --resume run7
"""


def train_transfer_run(run, registry: Path, eval_episodes: int) -> dict:
    """Train a transfer run to its end with progress on stderr, then evaluate and save its student."""
    from miktcli.workflows.session import run_to_end
    from miktcli.workflows.transfer import train_transfer

    sources = ", ".join(f"{t.name}@v{t.version}" for t in run.card.teachers) or "scratch"
    err.print(f"{run.id}: {run.card.method} {sources} → {run.card.env}, {run.card.total_steps} steps, "
              f"seed {run.card.seed} → {run.path}")
    note_compile(run)
    try:
        with training_progress(run.card.total_steps, run.card.steps_done, run.id) as show:
            return run_to_end(train_transfer(run, registry, eval_episodes), show)
    except KeyboardInterrupt:
        raise MiktError(f"interrupted; {run.id} keeps its last complete checkpoint",
                        hint=f"continue with: mikt transfer --resume {run.id}") from None


FLAG_HINTS = {  # library errors speak in domain terms; here they meet the flags that caused them
    "takes no teachers": "drop --from",
    "needs a teacher": "add --from NAME or NAME@vN",
    "encoder width": "--encoder-width must equal each teacher's state dim; leave it out to use the cards'",
    "requested": "--hidden must equal the teachers' hidden sizes; leave it out to use the cards'",
}


def with_flag_hint(error: MiktError) -> MiktError:
    if error.hint is None:
        error.hint = next((hint for text, hint in FLAG_HINTS.items() if text in str(error)), None)
    return error


# The flags that set MIKT's options (and its encoder check): meaningless for a method without options.
MIKT_OPTIONS = {"mi", "rl_encoder_grad", "coupling_schedule", "coupling_pi_coef", "coupling_vf_coef", "mi_coef",
                "lateral", "encoder_width"}


def transfer(
    ctx: typer.Context,
    teacher: list[str] = typer.Option(None, "--from", help="Teacher NAME or NAME@vN; repeat for several teachers."),
    to: str = typer.Option(None, "--to", help="Target environment."),
    method: str = typer.Option("mikt", "--method", help="mikt | vpg (PPO from scratch) | mlpp."),
    steps: StepsOption = 2_000_000,
    seed: SeedOption = 0,
    mi: bool = typer.Option(True, "--mi/--no-mi", help="Train the encoder with L_MI ('w/o MI' ablation)."),
    rl_encoder_grad: bool = typer.Option(
        True, "--rl-encoder-grad/--no-rl-encoder-grad", help="PPO gradient into the encoder (ablation: off)."),
    kl_coef: float = typer.Option(None, "--kl-coef", min=0, help="KL(pi||pi_old) weight (mikt 0.05, others 0)."),
    coupling_schedule: str = typer.Option("three-phase", "--coupling-schedule", help="three-phase | constant."),
    coupling_pi_coef: float = typer.Option(1.0, "--coupling-pi-coef", min=0),
    coupling_vf_coef: float = typer.Option(0.1, "--coupling-vf-coef", min=0),
    mi_coef: float = typer.Option(0.5, "--mi-coef", min=0),
    lateral: str = typer.Option(
        "identity", "--lateral", help="identity (the paper) | projection (the authors' code: learnable U per layer)."),
    encoder_width: list[int] = typer.Option(
        None, "--encoder-width", help="Optional check: must equal each teacher's state dim (read from its card)."),
    hidden: str = typer.Option(None, "--hidden", help="Optional check: must equal the teachers' hidden sizes."),
    num_envs: NumEnvsOption = 1,
    compile_loss: CompileOption = None,
    eval_episodes: int = typer.Option(10, "--eval-episodes", min=1, help="Episodes for the final evaluation."),
    resume: str = typer.Option(None, "--resume", help="Continue an interrupted transfer run."),
    as_json: JsonOption = False,
    registry: RegistryOption = DEFAULT_REGISTRY,
) -> None:
    from miktcli.cli.teacher import parse_hidden
    from miktcli.methods import get_method, transfer_methods
    from miktcli.registry.runs import open_resumable
    from miktcli.workflows.transfer import start_transfer

    setup_torch()
    reg = registry
    if resume:
        refuse_options_with_resume(ctx)
        run = open_resumable(reg, resume, "transfer")
    else:
        if to is None:
            raise MiktError("give the target environment with --to ENV (or --resume RUN)")
        if not get_method(method).for_transfer:
            raise MiktError(f"unknown method '{method}'; known: {', '.join(transfer_methods())}")
        if coupling_schedule not in ("three-phase", "constant"):
            raise MiktError(f"unknown coupling schedule '{coupling_schedule}'; known: three-phase, constant")
        if lateral not in ("identity", "projection"):
            raise MiktError(f"unknown --lateral '{lateral}'; known: identity, projection")
        mikt = {"coupling_schedule": coupling_schedule, "coupling_pi_coef": coupling_pi_coef,
                "coupling_vf_coef": coupling_vf_coef, "mi": mi, "mi_coef": mi_coef,
                "rl_encoder_grad": rl_encoder_grad, "lateral": lateral}
        if get_method(method).options is None:
            refuse_options_of_other_methods(ctx, method, MIKT_OPTIONS)
            mikt = None
        try:
            run = start_transfer(
                reg, to=to, method=method, teacher_refs=list(teacher or []), steps=steps, seed=seed,
                command=command_line(), kl_coef=kl_coef, num_envs=num_envs, options=mikt,
                compile_loss=compile_loss,
                encoder_widths=list(encoder_width) if encoder_width else None,
                hidden=parse_hidden(hidden) if hidden else None,
            )
        except MiktError as error:
            raise with_flag_hint(error) from None
        note_rounding(steps, run.card.total_steps)
    result = train_transfer_run(run, reg, eval_episodes)
    if as_json:
        print_json({"run": run.id, **result})
        return
    without = result["eval_without_teacher"]
    if "eval_with_teacher" in result:
        w = result["eval_with_teacher"]
        err.print(f"return with teacher {w['return_mean']:.1f} ± {w['return_std']:.1f}")
    err.print(f"return without teacher {without['return_mean']:.1f} ± {without['return_std']:.1f}")
    if "final_mixing" in result:
        weights = ", ".join(f"{k}={v:.3f}" for k, v in result["final_mixing_learned"].items())
        err.print(f"final student weights {weights}")
    print_data(run.id)
