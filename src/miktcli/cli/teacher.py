"""`mikt teacher`: train teachers with PPO and browse the teacher registry."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table
from rich.text import Text

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
    refuse_options_with_resume,
    setup_torch,
)
from miktcli.cli.console import err, out, print_data, print_json
from miktcli.cli.progress import training_progress
from miktcli.errors import MiktError

app = typer.Typer(
    help="Train teachers and browse the registry.\n\nExamples:\n\n  mikt teacher train centipede-four"
    "\n\n  mikt teacher train hopper --steps 1000000 --seed 1\n\n  mikt teacher list\n\n"
    "  mikt teacher show centipede-four@v1\n\n  mikt teacher import ppo_hopper.zip --env hopper --obs-stats stats.json",
    no_args_is_help=True,
)


def parse_hidden(text: str) -> list[int]:
    try:
        sizes = [int(s) for s in text.split(",")]  # an empty piece ("64,,64") is a typo, not a layer to skip
    except ValueError:
        raise MiktError(f"--hidden '{text}': expected comma-separated integers such as 64,64") from None
    if not sizes or any(s <= 0 for s in sizes):
        raise MiktError(f"--hidden '{text}': expected positive layer sizes such as 64,64")
    return sizes


@app.command("train")
def train(
    ctx: typer.Context,
    env: str = typer.Argument(None, help="Environment name (see `mikt envs`).", show_default=False),
    steps: StepsOption = 2_000_000,
    seed: SeedOption = 0,
    name: str = typer.Option(None, "--name", help="Teacher name in the registry (default: the env's name)."),
    num_envs: NumEnvsOption = 1,
    compile_loss: CompileOption = None,
    hidden: str = typer.Option("64,64", "--hidden", help="Hidden sizes of policy and value MLPs."),
    resume: str = typer.Option(None, "--resume", help="Continue an interrupted teacher run, e.g. run3."),
    registry: RegistryOption = DEFAULT_REGISTRY,
) -> None:
    """Train a teacher with PPO and add it to the registry as a new version."""
    from miktcli.registry.runs import open_resumable, open_run
    from miktcli.workflows.session import run_to_end
    from miktcli.workflows.teacher import start_teacher, train_teacher

    setup_torch()
    if resume:
        refuse_options_with_resume(ctx)
        run = open_resumable(registry, resume, "teacher")
    else:
        if env is None:
            raise MiktError("give an environment name, or --resume RUN")
        run = start_teacher(registry, env=env, steps=steps, seed=seed, name=name, num_envs=num_envs,
                            hidden=parse_hidden(hidden), command=command_line(), compile_loss=compile_loss)
        note_rounding(steps, run.card.total_steps)
    err.print(f"{run.id}: teacher on {run.card.env}, {run.card.total_steps} steps, seed {run.card.seed} → {run.path}")
    note_compile(run)
    try:
        with training_progress(run.card.total_steps, run.card.steps_done, run.id) as show:
            card = run_to_end(train_teacher(run, registry), show)
    except KeyboardInterrupt:
        steps_done = open_run(registry, run.id).card.steps_done
        raise MiktError(
            f"interrupted; {run.id} keeps its last complete checkpoint ({steps_done} steps)",
            hint=f"continue with: mikt teacher train --resume {run.id}",
        ) from None
    err.print(f"final mean return {card.final_return}, best {card.best_return}")
    print_data(card.ref)


@app.command("import")
def import_command(
    path: Path = typer.Argument(..., help="An SB3 PPO .zip or a CleanRL .cleanrl_model.", show_default=False),
    env: str = typer.Option(..., "--env", help="The environment it was trained on (see `mikt envs`)."),
    fmt: str = typer.Option(None, "--format", help="sb3 | cleanrl (default: from the file name)."),
    name: str = typer.Option(None, "--name", help="Teacher name in the registry (default: the env's name)."),
    obs_stats: Path = typer.Option(
        None, "--obs-stats", help='JSON {"mean": [...], "var": [...]}: the observation normaliser it was trained '
        "with (SB3's VecNormalize, CleanRL's NormalizeObservation)."),
    registry: RegistryOption = DEFAULT_REGISTRY,
) -> None:
    """Import a PPO policy trained with Stable-Baselines3 or CleanRL as a teacher. Nothing is unpickled."""
    from miktcli.workflows.teacher import import_teacher

    if fmt is None:
        fmt = "sb3" if path.suffix == ".zip" else "cleanrl" if path.suffix == ".cleanrl_model" else None
        if fmt is None:
            raise MiktError(f"{path}: cannot tell the format from the name", hint="pass --format sb3 or cleanrl")
    card = import_teacher(registry, path, fmt=fmt, env=env, name=name, obs_stats=obs_stats)
    err.print(f"imported {path.name} ({fmt}, {card.activation}, hidden {card.pi_hidden}) as {card.ref}")
    print_data(card.ref)


def _teacher_rows(reg: Path) -> list[dict]:
    from miktcli.registry.teachers import list_names, read_teacher_card, teachers_dir, versions

    rows = []
    for name in list_names(reg):
        for v in versions(reg, name):
            path = teachers_dir(reg) / name / f"v{v}.safetensors"
            stored_as = f"{name}@v{v}"  # where the file lies is what `eval` and `transfer` resolve
            try:
                card = read_teacher_card(path)  # the header only: no weights are loaded
                if card.ref != stored_as:
                    raise MiktError(f"{path}: the card names {card.ref} but the file is stored as {stored_as} "
                                    "(moved or tampered)")
                rows.append({"ref": stored_as, "card": card.model_dump(mode="json"), "path": str(path),
                             "error": None})
            except MiktError as e:
                rows.append({"ref": stored_as, "card": None, "path": str(path), "error": str(e)})
    return rows


@app.command("list")
def list_teachers(
    as_json: JsonOption = False,
    registry: RegistryOption = DEFAULT_REGISTRY,
) -> None:
    """List teachers and their versions (reads file headers only)."""
    rows = _teacher_rows(registry)
    unreadable = sum(r["error"] is not None for r in rows)
    if as_json:
        print_json(rows)
    else:
        _print_teacher_table(rows, registry)
    if unreadable:  # the readable ones are listed; the exit status says something is wrong
        raise MiktError(f"{unreadable} teacher file(s) in {registry} cannot be used (see the list)")


def _print_teacher_table(rows: list[dict], registry: Path) -> None:
    if not rows:
        err.print(f"no teachers in {registry}; train one with: mikt teacher train ENV")
        return
    table = Table("teacher", "env", "obs", "act", "hidden", "steps", "final return", "created")
    for r in rows:
        c = r["card"]
        if c is None:
            table.add_row(r["ref"], Text(f"unreadable: {r['error']}", style="red"), "", "", "", "", "", "")
            continue
        ret = "—" if c["final_return"] is None else f"{c['final_return']:.1f}"
        table.add_row(r["ref"], c["env"], str(c["obs_dim"]), str(c["act_dim"]),
                      "x".join(map(str, c["pi_hidden"])), f"{c['steps']:,}", ret, c["created"][:19])
    out.print(table)


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


@app.command("show")
def show(
    ref: str = typer.Argument(..., help="NAME, NAME@latest or NAME@vN."),
    as_json: JsonOption = False,
    registry: RegistryOption = DEFAULT_REGISTRY,
) -> None:
    """Show a teacher's card after verifying the file (shapes and sha256)."""
    from miktcli.registry.teachers import load_teacher

    teacher = load_teacher(registry, ref)
    data = teacher.card.model_dump(mode="json")
    if as_json:
        print_json(data)
    else:
        render_card(data)
