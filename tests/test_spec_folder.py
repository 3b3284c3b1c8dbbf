"""A spec folder holding things that are not spec files: a folder named `x.toml` is named as not
a spec, and never hides the good specs from `mikt envs` nor breaks gym.make."""

import ast
import subprocess
import sys
from pathlib import Path

from typer.testing import CliRunner

from helpers import spec_dir
from miktcli.cli.app import app


def test_a_folder_named_toml_does_not_break_mikt_envs(tmp_path, monkeypatch):
    spec_dir(tmp_path, monkeypatch)
    (tmp_path / "specs" / "stray.toml").mkdir()
    r = CliRunner().invoke(app, ["envs"])
    assert "hopper" in r.stdout and "centipede-four" in r.stdout, r.output
    assert "stray.toml: a folder, not a spec file" in r.output and "internal error" not in r.output
    r = CliRunner().invoke(app, ["envs", "show", "stray"])
    assert r.exit_code == 1 and "unknown environment 'stray'; known: " in r.output and "hopper" in r.output


def test_a_folder_named_toml_does_not_break_gym_make(tmp_path, monkeypatch):
    spec_dir(tmp_path, monkeypatch)
    (tmp_path / "specs" / "stray.toml").mkdir()
    code = ("import gymnasium as gym\n"
            "env = gym.make('miktcli.gym:mikt/hopper')\n"
            "import miktcli.gym\n"
            "print(sorted(miktcli.gym.ENV_IDS))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                       env={**__import__("os").environ, "PYTHONPATH": str(Path(__file__).parents[1] / "src")})
    assert r.returncode == 0, r.stderr
    ids = ast.literal_eval(r.stdout.strip())
    # the user's specs and the shipped ones (layered), and no id for the folder
    assert {"mikt/centipede-four", "mikt/hopper"} <= set(ids) and "mikt/stray" not in ids
