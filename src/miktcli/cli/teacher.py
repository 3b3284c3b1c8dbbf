"""`mikt teacher`: train teachers with PPO and browse the teacher registry."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table
from rich.text import Text

from miktcli.cli.common import command_line, note_rounding, registry_option, resolve_registry, setup_torch
from miktcli.cli.console import err, out, print_data, print_json
from miktcli.cli.progress import track_training
from miktcli.errors import MiktError

app = typer.Typer(
    help="Train teachers and browse the registry.\n\nExamples:\n\n  mikt teacher train centipede-four"
    "\n\n  mikt teacher train hopper --steps 1000000 --seed 1\n\n  mikt teacher list\n\n"
    "  mikt teacher show centipede-four@v1",
    no_args_is_help=True,
)


def parse_hidden(text: str) -> list[int]:
    try:
        sizes = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise MiktError(f"--hidden '{text}': expected comma-separated integers such as 64,64") from None
    if not sizes or any(s <= 0 for s in sizes):
        raise MiktError(f"--hidden '{text}': expected positive layer sizes such as 64,64")
    return sizes


@app.command("train")
def train(
    env: str = typer.Argument(None, help="Environment name (see `mikt envs`).", show_default=False),
    steps: int = typer.Option(2_000_000, "--steps", min=1, help="Environment steps (the paper: 2M)."),
    seed: int = typer.Option(0, "--seed", min=0, max=2**32 - 1, help="Random seed."),
    name: str = typer.Option(None, "--name", help="Teacher name in the registry (default: the env's name)."),
    num_envs: int = typer.Option(1, "--num-envs", min=1, help="Synchronous environments (the paper: 1)."),
    hidden: str = typer.Option("64,64", "--hidden", help="Hidden sizes of policy and value MLPs."),
    resume: str = typer.Option(None, "--resume", help="Continue an interrupted teacher run, e.g. run3."),
    registry: Path = registry_option(),
) -> None:
    """Train a teacher with PPO and add it to the registry as a new version."""
    from miktcli.methods import build_agent
    from miktcli.ppo import PPOConfig
    from miktcli.registry.runs import open_resumable, open_run
    from miktcli.registry.teachers import check_name
    from miktcli.workflows.session import Job, new_run, publish_teacher_from_job

    setup_torch()
    reg = resolve_registry(registry)
    if resume:
        run = open_resumable(reg, resume, "teacher")
    else:
        if env is None:
            raise MiktError("give an environment name, or --resume RUN")
        teacher_name = check_name(env if name is None else name)
        sizes = parse_hidden(hidden)
        config = {"ppo": PPOConfig(num_envs=num_envs).model_dump(), "pi_hidden": sizes, "vf_hidden": sizes,
                  "teacher_name": teacher_name}
        run = new_run(reg, kind="teacher", env=env, method="ppo", seed=seed, total_steps=steps, config=config,
                      command=command_line())
        note_rounding(steps, run.card.total_steps)
    try:
        with Job(run, reg, build_agent) as job:
            err.print(f"{run.id}: teacher on {run.card.env}, {run.card.total_steps} steps, seed {run.card.seed} "
                      f"→ {run.path}")
            for _ in track_training(job.iterations(), run.card.total_steps, job.trainer.global_step, run.id):
                pass
            card = publish_teacher_from_job(job, run.card.config["teacher_name"])
    except KeyboardInterrupt:
        steps_done = open_run(reg, run.id).card.steps_done
        raise MiktError(
            f"interrupted; {run.id} keeps its last complete checkpoint ({steps_done} steps)",
            hint=f"continue with: mikt teacher train --resume {run.id}",
        ) from None
    err.print(f"final mean return {card.final_return}, best {card.best_return}")
    print_data(card.ref)


def _teacher_rows(reg: Path) -> list[dict]:
    from miktcli.registry.teachers import list_names, read_teacher_card, teachers_dir, versions

    rows = []
    for name in list_names(reg):
        for v in versions(reg, name):
            path = teachers_dir(reg) / name / f"v{v}.safetensors"
            try:
                card = read_teacher_card(path)  # the header only: no weights are loaded
                rows.append({"ref": card.ref, "card": card.model_dump(mode="json"), "path": str(path),
                             "error": None})
            except MiktError as e:
                rows.append({"ref": f"{name}@v{v}", "card": None, "path": str(path), "error": str(e)})
    return rows


@app.command("list")
def list_teachers(
    as_json: bool = typer.Option(False, "--json", help="Print as JSON."),
    registry: Path = registry_option(),
) -> None:
    """List teachers and their versions (reads file headers only)."""
    reg = resolve_registry(registry)
    rows = _teacher_rows(reg)
    if as_json:
        print_json(rows)
        return
    if not rows:
        err.print(f"no teachers in {reg}; train one with: mikt teacher train ENV")
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
    table = Table(show_header=False, box=None)
    for key, value in data.items():
        if isinstance(value, dict):
            value = ", ".join(f"{k}={v}" for k, v in value.items())
        table.add_row(key, str(value))
    out.print(table)


@app.command("show")
def show(
    ref: str = typer.Argument(..., help="NAME, NAME@latest or NAME@vN."),
    as_json: bool = typer.Option(False, "--json", help="Print as JSON."),
    registry: Path = registry_option(),
) -> None:
    """Show a teacher's card after verifying the file (shapes and sha256)."""
    from miktcli.registry.teachers import load_teacher

    teacher = load_teacher(resolve_registry(registry), ref)
    data = teacher.card.model_dump(mode="json")
    if as_json:
        print_json(data)
    else:
        render_card(data)
