"""Helpers shared by the test modules, so that no test module imports another: the CLI runner and the strict
`mikt()` call, spec folders, teacher files rewritten consistently, fake completed runs, import fixtures, a small
grid file."""

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load as st_load
from safetensors.torch import save as st_save
from torch import nn
from typer.testing import CliRunner

from miktcli.cli.app import app
from miktcli.registry.cards import TeacherCard
from miktcli.registry.files import CARD_KEY, tensors_sha256

runner = CliRunner()


def mikt(*args, code=0):
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == code, result.output
    if code == 1:  # a known failure ends with one line (plus an optional hint), never a traceback
        lines = [ln for ln in result.output.splitlines() if ln.strip()]
        first = next(i for i, ln in enumerate(lines) if ln.startswith("Error: "))
        assert all(ln.startswith(("Error: ", "Hint: ")) for ln in lines[first:]), result.output
        assert "Traceback" not in result.output, result.output
    return result


def runs(registry):
    return json.loads(mikt("runs", "--json").stdout) if (registry / "runs").exists() else []


def rewrite_teacher(path, update=None, tensors=None):
    """Rewrite a teacher file consistently (card sha256 matches the policy's tensors, those but the carried
    environment's `env/…`): well-formed but wrong."""
    from safetensors import safe_open

    from miktcli.registry.carried import split_carried

    with safe_open(str(path), "pt") as f:
        card = TeacherCard.model_validate_json(f.metadata()[CARD_KEY])
    tensors = st_load(path.read_bytes()) if tensors is None else tensors
    policy, carried = split_carried(tensors)
    card = card.model_copy(update={**(update or {}), "tensors_sha256": tensors_sha256(policy),
                                   "env_files_sha256": tensors_sha256(carried) if carried else None})
    path.write_bytes(st_save(tensors, metadata={CARD_KEY: card.model_dump_json()}))


def spec_dir(tmp_path, monkeypatch, **files):
    from miktcli.envs.spec import envspecs_dir

    folder = tmp_path / "specs"
    folder.mkdir()
    for stem in ("hopper", "centipede-four"):
        (folder / f"{stem}.toml").write_text((envspecs_dir() / f"{stem}.toml").read_text())
    for stem, body in files.items():
        (folder / f"{stem}.toml").write_text(body)
    monkeypatch.setenv("MIKT_ENVSPECS", str(folder))


FIXTURE = Path(__file__).parent / "fixtures" / "sb3_ppo_hopper_tiny.zip"  # made by SB3 (make_sb3_fixture.py)


def sb3_actions(obs: np.ndarray) -> np.ndarray:
    """What the fixture's own layers compute (relu MlpPolicy), from its raw tensors."""
    with zipfile.ZipFile(FIXTURE) as z:
        sd = torch.load(io.BytesIO(z.read("policy.pth")), weights_only=True)
    x = torch.as_tensor(obs, dtype=torch.float32)
    for j in (0, 2):
        x = torch.relu(x @ sd[f"mlp_extractor.policy_net.{j}.weight"].T + sd[f"mlp_extractor.policy_net.{j}.bias"])
    return (x @ sd["action_net.weight"].T + sd["action_net.bias"]).numpy()


def cleanrl_agent(obs_dim, act_dim):
    """The Agent of CleanRL's ppo_continuous_action.py, layer for layer."""
    agent = nn.Module()
    agent.critic = nn.Sequential(nn.Linear(obs_dim, 64), nn.Tanh(), nn.Linear(64, 64), nn.Tanh(), nn.Linear(64, 1))
    agent.actor_mean = nn.Sequential(nn.Linear(obs_dim, 64), nn.Tanh(), nn.Linear(64, 64), nn.Tanh(),
                                     nn.Linear(64, act_dim))
    agent.actor_logstd = nn.Parameter(torch.full((1, act_dim), -0.5))
    return agent


def fixture_with(tmp_path, name, data=None, weights=None, compress=zipfile.ZIP_STORED):
    """The SB3 fixture with its `data` or weights replaced."""
    path = tmp_path / name
    with zipfile.ZipFile(FIXTURE) as z, zipfile.ZipFile(path, "w", compress) as out:
        out.writestr("data", z.read("data") if data is None else data)
        out.writestr("policy.pth", z.read("policy.pth") if weights is None else weights)
    return path


def fake_run(registry, env, method, seed, curve, eval_return, mixing=None, teachers=(), per_row=None):
    """A completed run with a given return curve (one point per 2048-step iteration); `per_row`, where given,
    holds more metrics for each iteration (one dict each)."""
    from miktcli.engine.ppo import PPOConfig
    from miktcli.registry.cards import RunConfig, TeacherRef
    from miktcli.registry.runs import create_run

    config = RunConfig(ppo=PPOConfig(), pi_hidden=[64, 64], vf_hidden=[64, 64])
    refs = [TeacherRef(name=name, version=1, sha256="", obs_dim=1, env="x") for name in teachers]
    run = create_run(registry, kind="transfer", env=env, method=method, seed=seed, total_steps=2048 * len(curve),
                     config=config, command="test", teachers=refs, code_version="test", packages={})
    for i, ret in enumerate(curve, start=1):
        row = {"iteration": i, "steps": 2048 * i, "return_mean": ret, **(mixing or {})}
        row.update(per_row[i - 1] if per_row is not None else {})
        run.append_metrics(row)
    result = {"eval_without_teacher": {"return_mean": eval_return}}
    if mixing:
        result["final_mixing_learned"] = mixing
    run.save_card(status="completed", steps_done=2048 * len(curve), result=result)
    return run.id


def robot_with_mesh_and_include(folder):
    """An MJCF robot that loads a mesh (a one-tetrahedron OBJ) and includes a file holding its actuator."""
    (folder / "meshes").mkdir(parents=True)
    (folder / "meshes" / "foot.obj").write_text("v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\n"
                                                "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    (folder / "motors.xml").write_text('<mujoco><actuator><motor joint="hip" gear="10"/></actuator></mujoco>')
    (folder / "bot.xml").write_text(
        '<mujoco><compiler meshdir="meshes"/><asset><mesh name="foot" file="foot.obj"/></asset><worldbody>'
        '<geom type="plane" size="5 5 .1"/><body name="base" pos="0 0 0.5"><freejoint/>'
        '<geom type="sphere" size="0.1"/><body name="leg"><joint name="hip" type="hinge" axis="0 1 0"/>'
        '<geom type="mesh" mesh="foot"/></body></body></worldbody><include file="motors.xml"/></mujoco>')
    return folder / "bot.xml"


def vpg_grid(folder, steps=2048, seeds=(0,), extra=""):
    """A grid file (folder/g.toml) of one pair, x → hopper, and vpg alone; `extra` holds more top-level keys."""
    grid = folder / "g.toml"
    grid.write_text(f'name = "g"\nsteps = {steps}\nseeds = {list(seeds)}\n{extra}[[pairs]]\nfrom = ["x"]\n'
                    'to = "hopper"\n[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    return grid


TINY = ("--steps", 2048)  # one PPO iteration: a run that finishes in seconds


def interrupted(run):
    """The run as Ctrl-C leaves it: its card says interrupted."""
    run.save_card(status="interrupted")
    return run


def ctrl_c_at_second_call(monkeypatch, owner, name):
    """`owner.name` raises KeyboardInterrupt (as Ctrl-C would) on its second call; the returned function puts
    the original back, so training runs normally again."""
    original, calls = getattr(owner, name), {"n": 0}

    def interrupted(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return original(self, *args, **kwargs)

    monkeypatch.setattr(owner, name, interrupted)
    return lambda: monkeypatch.setattr(owner, name, original)
