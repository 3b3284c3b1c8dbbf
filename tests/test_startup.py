"""What a `mikt` process loads before its first step: the start-up is most of a short run's time, so the heavy
pieces stay out of commands that never use them."""

import json
import os
import subprocess
import sys

import pytest

PROBE = """
import json, sys
from typer.testing import CliRunner
from miktcli.cli.app import app
result = CliRunner().invoke(app, sys.argv[1:])
heavy = ["torch._dynamo", "scipy", "matplotlib", "miktcli.studies", "ray"]
print(json.dumps({"code": result.exit_code, "output": result.output,
                  "loaded": [m for m in heavy if m in sys.modules]}))
"""


def loaded_by(*args, folder) -> list[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("MIKT_REGISTRY", "MIKT_ENVSPECS")}
    env["MIKT_PACKAGED_TEACHERS"] = "1"  # a user's empty folder sees the teachers that ship with mikt
    done = subprocess.run([sys.executable, "-c", PROBE, *map(str, args)], capture_output=True, text=True,
                          check=True, cwd=folder, env=env)
    report = json.loads(done.stdout.splitlines()[-1])
    assert report["code"] == 0, report["output"]
    return report["loaded"]


@pytest.mark.slow
def test_training_a_teacher_loads_neither_the_compiler_nor_the_study_machinery(tmp_path):
    # torch.optim would import torch._dynamo (1-2 s); the engine's Adam calls the same fused kernel without it
    assert loaded_by("teacher", "train", "hopper", "--steps", 1024, folder=tmp_path) == []


@pytest.mark.slow
def test_a_study_still_loads_its_machinery(tmp_path):
    # the probe's control: what the first test finds missing is there when a command needs it
    loaded = loaded_by("study", "run", "--example", "tiny", folder=tmp_path)
    assert {"miktcli.studies", "scipy"} <= set(loaded)
