"""`mikt runs --json | head -n 1`: a reader that closes the pipe early ends mikt quietly, with
status 1 and nothing on stderr (as rich does for tables), instead of "Error: Broken pipe"."""

import os
import subprocess
import sys
from pathlib import Path

import pytest


@pytest.mark.slow  # process-level: runs mikt in a subprocess
@pytest.mark.parametrize("args", [("runs", "--json"), ("runs",), ("envs",)])
def test_a_closed_stdout_ends_quietly(tmp_path, args):
    from miktcli.workflows.transfer import start_transfer

    start_transfer(tmp_path / "reg", to="hopper", method="vpg", teacher_refs=[], steps=2048, seed=0, command="t")
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).parents[1] / "src"), "MIKT_REGISTRY": str(tmp_path / "reg")}
    p = subprocess.Popen([sys.executable, "-m", "miktcli", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         env=env)
    p.stdout.close()  # the reader is gone before mikt writes anything
    _, stderr = p.communicate(timeout=300)
    assert stderr.decode() == "" and p.returncode == 1
