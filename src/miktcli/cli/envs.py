"""`mikt envs`: list, show and render the environments described by envspecs/*.toml."""

from __future__ import annotations

import statistics
from pathlib import Path

import typer
from rich.table import Table
from rich.text import Text

from miktcli.cli.common import JsonOption
from miktcli.cli.console import err, out, print_data, print_error, print_json

app = typer.Typer(
    help="List, show and render environments.\n\nExamples:\n\n  mikt envs\n\n  mikt envs show centipede-six"
    "\n\n  mikt envs render ant --out ant.png\n\n  mikt envs add my_robot.xml --name my-robot",
    invoke_without_command=True,
    no_args_is_help=False,
)


def _family(spec) -> str:
    if spec.family == "mjcf":
        return f"mjcf ({spec.xml})"
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
    from miktcli.envs.frames import render_frame, save_png
    from miktcli.outfiles import prepare_output

    prepare_output(out_path)
    from miktcli.envs.failures import env_failure

    env = make_env(name, render_mode="rgb_array")
    try:
        try:
            env.reset(seed=seed)
        except Exception as error:  # noqa: BLE001 - the env's own code (MuJoCo's FatalError too): name its spec
            raise env_failure(env, error, "reset") from error
        frame = render_frame(env)
    finally:
        env.close()
    save_png(frame, out_path)
    err.print(f"wrote {out_path} ({frame.shape[1]}x{frame.shape[0]})")
    print_data(out_path)


@app.command("add")
def add(
    xml: Path = typer.Argument(..., help="An MJCF file (a robot with actuators and a free or slide root joint).",
                               show_default=False),
    name: str = typer.Option(..., "--name", help="The environment's name, e.g. my-robot."),
    torso: str = typer.Option(None, "--torso", help="The body that carries the root joint (default: the body of "
                              "the free joint, else the first body with slide joints)."),
) -> None:
    """Add your own robot: write an `mjcf` spec into $MIKT_ENVSPECS (else ./envspecs), with the XML and the
    files it loads copied beside it. Prints the model's dims, actuators and torso; writes nothing on an error."""
    from miktcli.workflows.add_env import add_mjcf

    added = add_mjcf(xml, name, torso=torso)
    spec, facts = added.spec, added.facts
    err.print(f"{xml}: obs {spec.obs_dim}, act {spec.act_dim}, nq {facts['nq']}, nv {facts['nv']}, "
              f"timestep {facts['timestep']:g} s x frame_skip {spec.frame_skip}")
    err.print(f"torso: {added.root}")
    err.print(f"actuators ({len(facts['actuators'])}): {', '.join(facts['actuators'])}")
    if added.copied:
        extra = f" and {len(added.files)} file(s) it loads" if added.files else ""
        err.print(f"copied the XML{extra} to {added.xml_path.parent}")
    else:
        err.print(f"the spec uses {added.xml_path} in place ({added.why_in_place}): keep it there")
    for note in added.notes:
        prefix = ("warning: ", "yellow") if note.kind == "warning" else ""
        err.print(Text.assemble(prefix, note.text, (f" (spec key: {note.key})", "dim")))
    for result in added.probes:
        what = "a zero action" if result.policy == "zero" else "random actions"
        spread = f" ± {statistics.pstdev(result.returns):.1f}" if len(result.returns) > 1 else ""
        err.print(f"probe, {what}: return {result.mean_return:.1f}{spread} over {result.mean_length:.0f} steps, "
                  f"moved {statistics.fmean(result.distances):+.2f} m ({len(result.returns)} episode(s))")
    healthy = "none" if spec.healthy_z_min is None else f"root height > {spec.healthy_z_min}"
    err.print(f"wrote {added.spec_path} (health check: {healthy}; edit the file to change any term)")
    print_data(added.spec_path)
