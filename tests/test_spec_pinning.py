"""A run and a teacher record the environment they trained on; an edited spec or model file is refused by
resume, eval and studies in one line, instead of silently training or scoring another body or reward."""

import json
import re
from pathlib import Path

import gymnasium as gym
import pytest

from helpers import mikt

ASSETS = Path(gym.__file__).parent / "envs" / "mujoco" / "assets"


@pytest.fixture()
def my_hopper(specs):
    mikt("envs", "add", ASSETS / "hopper.xml", "--name", "my-hopper")
    return specs


def edit(specs, **fields):
    path = specs / "my-hopper.toml"
    text = path.read_text()
    for key, value in fields.items():
        text = re.sub(rf"^{key} = .*$", f"{key} = {value}", text, flags=re.M)
    path.write_text(text)


def test_a_teacher_is_not_evaluated_on_an_edited_spec(my_hopper, registry):
    mikt("teacher", "train", "my-hopper", "--steps", 2048, "--name", "t")
    mikt("eval", "t", "--episodes", 1)
    edit(my_hopper, ctrl_cost_weight=500)
    out = mikt("eval", "t", "--episodes", 1, code=1).output
    assert "environment 'my-hopper' changed since it was trained (ctrl_cost_weight: 0.001 then, 500.0 now)" in out


@pytest.mark.slow
def test_a_run_records_its_spec_and_is_neither_resumed_nor_evaluated_after_an_edit(
        my_hopper, registry, ctrl_c_at_second_update):
    mikt("transfer", "--to", "my-hopper", "--method", "vpg", "--steps", 6144, "--eval-episodes", 1, code=1)
    card = json.loads((registry / "runs" / "run1" / "run.json").read_text())
    assert card["env_spec"]["ctrl_cost_weight"] == 0.001 and len(card["env_fingerprint"]) == 64
    edit(my_hopper, ctrl_cost_weight=500)
    out = mikt("transfer", "--resume", "run1", code=1).output
    assert "cannot train run1: environment 'my-hopper' changed since it started" in out
    assert "cannot evaluate run1" in mikt("eval", "run1", "--episodes", 1, code=1).output
    edit(my_hopper, ctrl_cost_weight=0.001)  # put back: the same fingerprint, the run goes on
    ctrl_c_at_second_update()
    mikt("transfer", "--resume", "run1")


def test_an_edited_model_file_counts_as_a_change(my_hopper, registry, ctrl_c_at_second_update):
    mikt("transfer", "--to", "my-hopper", "--method", "vpg", "--steps", 6144, "--eval-episodes", 1, code=1)
    xml = my_hopper / "my-hopper" / "hopper.xml"
    xml.write_text(xml.read_text().replace('name="torso"', 'name="torso" ', 1))  # one byte more
    assert "changed since it started" in mikt("transfer", "--resume", "run1", code=1).output


@pytest.mark.slow
def test_a_study_refuses_to_mix_cells_trained_before_and_after_an_edit(my_hopper, registry, tmp_path):
    grid = tmp_path / "g.toml"
    grid.write_text('name = "g"\nsteps = 2048\nseeds = [0]\neval_episodes = 1\nbaseline = "vpg"\n'
                    '[[pairs]]\nfrom = ["x"]\nto = "my-hopper"\n[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    mikt("study", grid, "--out", tmp_path / "out")
    grid.write_text(grid.read_text().replace("seeds = [0]", "seeds = [0, 1]"))
    edit(my_hopper, ctrl_cost_weight=500)
    out = mikt("study", grid, "--out", tmp_path / "out", code=1).output
    assert "cell ->my-hopper|vpg|0 (run1): environment 'my-hopper' changed since that cell started" in out
    assert sorted(p.name for p in (registry / "runs").iterdir()) == ["run1"]  # no cell on the edited body
