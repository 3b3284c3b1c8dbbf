"""`mikt teacher`: train teachers with PPO and browse the teacher registry."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table
from rich.text import Text

from miktcli.cli.cards import render_card
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
    note_compile,
    note_env_copy,
    note_rounding,
    note_teacher_env,
    parse_hidden,
    parse_ppo_settings,
    refuse_options_with_resume,
    setup_torch,
)
from miktcli.cli.console import err, out, print_data, print_json
from miktcli.cli.progress import training_progress
from miktcli.errors import MiktError
from miktcli.registry import location

app = typer.Typer(
    help="Train teachers and browse the registry.\n\nExamples:\n\n  mikt teacher train centipede-four"
    "\n\n  mikt teacher train hopper --steps 1000000 --seed 1\n\n  mikt teacher list\n\n"
    "  mikt teacher show centipede-four@v1\n\n  mikt teacher add run7 --name six-from-four\n\n"
    "  mikt teacher import ppo_hopper.zip --env hopper --obs-stats stats.json",
    no_args_is_help=True,
)


@app.command("train")
def train(
    ctx: typer.Context,
    env: str = typer.Argument(None, help="Environment name (see `mikt envs`).", show_default=False),
    steps: StepsOption = 2_000_000,
    seed: SeedOption = 0,
    name: str = typer.Option(None, "--name", help="Teacher name in the registry (default: the env's name)."),
    num_envs: NumEnvsOption = 1,
    compile_loss: CompileOption = None,
    ppo: PPOSettingsOption = None,
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
        change_update_mode_on_resume(run, compile_loss)
    else:
        if env is None:
            raise MiktError("give an environment name, or --resume RUN")
        run = start_teacher(registry, env=env, steps=steps, seed=seed, name=name, num_envs=num_envs,
                            hidden=parse_hidden(hidden), command=command_line(), compile_loss=compile_loss,
                            ppo_settings=parse_ppo_settings(ppo))
        note_rounding(steps, run.card.total_steps)
        note_env_copy(run)
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
    note_teacher_env(card)
    print_data(card.ref)


@app.command("add")
def add_command(
    run: str = typer.Argument(..., help="A completed transfer run (runN, or last).", show_default=False),
    name: str = typer.Option(..., "--name", help="Teacher name in the registry (a new name, or the next "
                             "version of one)."),
    registry: RegistryOption = DEFAULT_REGISTRY,
) -> None:
    """Add a transfer run's teacher-free student as a teacher, so it can teach in turn (`--from NAME`)."""
    from miktcli.workflows.teacher import add_student_as_teacher

    card = add_student_as_teacher(registry, run, name)
    taught = ", ".join(card.trained_with) or "no teacher"
    err.print(f"added {card.source_run}'s student ({card.method} from {taught}, on {card.env}) as {card.ref}")
    note_teacher_env(card)
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
    activation: str = typer.Option(
        None, "--activation", help="tanh | relu, for files that cannot tell (CleanRL; default tanh, recorded as "
        "assumed). SB3 zips record theirs."),
    registry: RegistryOption = DEFAULT_REGISTRY,
) -> None:
    """Import a PPO policy trained with Stable-Baselines3 or CleanRL as a teacher. Nothing is unpickled."""
    from miktcli.workflows.teacher import import_teacher

    if fmt is None:
        fmt = "sb3" if path.suffix == ".zip" else "cleanrl" if path.suffix == ".cleanrl_model" else None
        if fmt is None:
            raise MiktError(f"{path}: cannot tell the format from the name", hint="pass --format sb3 or cleanrl")
    card = import_teacher(registry, path, fmt=fmt, env=env, name=name, obs_stats=obs_stats, activation=activation)
    err.print(f"imported {path.name} ({fmt}, {card.activation}, hidden {card.pi_hidden}) as {card.ref}")
    _warn_if_shadowing(registry, card, fmt)
    note_teacher_env(card)
    for what in ("activation", "obs_stats"):  # say what was assumed rather than read
        if str(card.imported_from.get(what, "")).startswith(("assumed", "none given")):
            err.print(f"{what}: {card.imported_from[what]}")
    print_data(card.ref)


def _warn_if_shadowing(registry: Path, card, fmt: str) -> None:
    """An import under a name that has versions (the default name is the env's, that of the shipped teachers)
    changes what that name means without a version: grids (`from = ["hopper"]`), transfers and evals."""
    from miktcli.workflows.teacher import shadowed_teacher

    try:
        older = shadowed_teacher(registry, card)
    except MiktError as e:
        err.print(f"warning: {card.ref} is now what `{card.name}` means; its previous version is unreadable: {e}")
        return
    if older is None:
        return
    made = (f"imported from {older.imported_from.get('format', '?')}" if older.imported_from
            else f"trained by mikt, {older.steps:,} steps")
    err.print(f"warning: {card.ref} (imported from {fmt}) is now what `{card.name}` means, in place of {older.ref} "
              f"({made}): grids, transfers and evals that name `{card.name}` without a version get this import; "
              f"name {older.ref} to keep it, or import under another --name (a study started before keeps its "
              "pinned version)")


def _teacher_rows(reg: Path) -> list[dict]:
    from miktcli.registry.teachers import read_teacher_card, teacher_files

    rows = []
    for f in teacher_files(reg):
        stored_as = f.ref  # where the file lies is what `eval` and `transfer` resolve
        source = "local (over packaged)" if f.shadows_packaged else f.source
        try:
            card = read_teacher_card(f.path)  # the header only: no weights are loaded
            if card.ref != stored_as:
                raise MiktError(f"{f.path}: the card names {card.ref} but the file is stored as {stored_as} "
                                "(moved or tampered)")
            rows.append({"ref": stored_as, "source": source, "card": card.model_dump(mode="json"),
                         "path": str(f.path), "error": None})
        except MiktError as e:
            rows.append({"ref": stored_as, "source": source, "card": None, "path": str(f.path), "error": str(e)})
    return rows


@app.command("list")
def list_teachers(
    as_json: JsonOption = False,
    registry: RegistryOption = DEFAULT_REGISTRY,
) -> None:
    """List teachers and their versions (reads file headers only).

    `source` says where each comes from: `local` (the registry folder) or `packaged` (shipped with mikt,
    read-only; a local file of the same name and version wins). MIKT_PACKAGED_TEACHERS=0 hides the packaged ones."""
    rows = _teacher_rows(registry)
    unreadable = sum(r["error"] is not None for r in rows)
    if as_json:
        print_json(rows)
    else:
        _print_teacher_table(rows, registry)
    if unreadable:  # the readable ones are listed; the exit status says something is wrong
        raise MiktError(f"{unreadable} teacher file(s) in registry {location.describe(registry)} cannot be used "
                        "(see the list)")


def _print_teacher_table(rows: list[dict], registry: Path) -> None:
    if not rows:
        err.print(f"no teachers in registry {location.describe(registry)}; train one with: mikt teacher train ENV")
        err.print(f"Hint: {location.HINT}")
        return
    table = Table("teacher", "source", "env", "obs", "act", "hidden", "steps", "final return", "created")
    for r in rows:
        c = r["card"]
        if c is None:
            table.add_row(r["ref"], r["source"], Text(f"unreadable: {r['error']}", style="red"),
                          "", "", "", "", "", "")
            continue
        ret = "—" if c["final_return"] is None else f"{c['final_return']:.1f}"
        table.add_row(r["ref"], r["source"], c["env"], str(c["obs_dim"]), str(c["act_dim"]),
                      "x".join(map(str, c["pi_hidden"])), f"{c['steps']:,}", ret, c["created"][:19])
    out.print(table)


@app.command("show")
def show(
    ref: str = typer.Argument(..., help="NAME, NAME@latest or NAME@vN."),
    as_json: JsonOption = False,
    registry: RegistryOption = DEFAULT_REGISTRY,
) -> None:
    """Show a teacher's card after verifying the file (shapes and sha256), and where the file comes from
    (`local` or `packaged`)."""
    from miktcli.registry.teachers import load_teacher

    teacher = load_teacher(registry, ref)
    data = {**teacher.card.model_dump(mode="json"), "source": teacher.source, "path": str(teacher.path)}
    if as_json:
        print_json(data)
    else:
        render_card(data)
