"""`mikt envs`: list, show and render the environments described by envspecs/*.toml."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from miktcli.cli.common import JsonOption
from miktcli.cli.console import err, out, print_data, print_error, print_json

app = typer.Typer(
    help="List, show and render environments.\n\nExamples:\n\n  mikt envs\n\n  mikt envs show centipede-six"
    "\n\n  mikt envs render ant --out ant.png",
    invoke_without_command=True,
    no_args_is_help=False,
)


def _family(spec) -> str:
    return "centipede" if spec.family == "centipede" else f"gymnasium ({spec.id})"


@app.callback(invoke_without_command=True)
def list_envs(
    ctx: typer.Context,
    as_json: JsonOption = False,
) -> None:
    """List the environments (name, family, obs dim, act dim, notes)."""
    from miktcli.envs.spec import scan_specs

    if ctx.invoked_subcommand is not None:
        return
    specs, bad = scan_specs()
    if as_json:
        print_json([s.model_dump() for s in specs])
    else:
        table = Table("name", "family", "obs dim", "act dim", "notes")
        for s in specs:
            table.add_row(s.name, _family(s), str(s.obs_dim), str(s.act_dim), s.notes)
        out.print(table)
    if bad:  # the good specs are listed; each bad file is named, and the exit code says something was wrong
        for problem in bad[1:]:
            print_error(problem)
        raise bad[0]


@app.command("show")
def show(
    name: str = typer.Argument(..., help="Environment name, e.g. centipede-six."),
    as_json: JsonOption = False,
) -> None:
    """Show one spec and the facts of its built model (bodies, joints, actuators)."""
    from miktcli.envs import load_spec, make_env, model_facts

    spec = load_spec(name)
    env = make_env(spec)
    facts = model_facts(env)
    env.close()
    if as_json:
        print_json({"spec": spec.model_dump(), "model": facts})
        return
    table = Table(show_header=False, box=None)
    for key, value in spec.model_dump().items():
        table.add_row(key, str(value))
    table.add_row("nq / nv", f"{facts['nq']} / {facts['nv']}")
    table.add_row("timestep", f"{facts['timestep']:g} s")
    for key in ("bodies", "joints", "actuators"):
        table.add_row(f"{key} ({len(facts[key])})", ", ".join(facts[key]))
    out.print(table)


@app.command("render")
def render(
    name: str = typer.Argument(..., help="Environment name."),
    out_path: Path = typer.Option(Path("frame.png"), "--out", "-o", help="PNG file to write."),
    seed: int = typer.Option(0, "--seed", min=0, max=2**32 - 1, help="Reset seed."),
) -> None:
    """Render one offscreen frame after a reset (headless, no GPU needed)."""
    from miktcli.envs import make_env
    from miktcli.outfiles import prepare_output
    from miktcli.render import render_frame, save_png

    prepare_output(out_path)
    env = make_env(name, render_mode="rgb_array")
    try:
        env.reset(seed=seed)
        frame = render_frame(env)
    finally:
        env.close()
    save_png(frame, out_path)
    err.print(f"wrote {out_path} ({frame.shape[1]}x{frame.shape[0]})")
    print_data(out_path)
