"""Every PPO setting can be changed from the command line (`--ppo KEY=VALUE`) and a grid (`ppo = {…}`), is
validated by PPOConfig, and is recorded in the run's card."""

import json

import pytest

from helpers import mikt


def test_a_setting_given_with_ppo_is_recorded_in_the_card(registry):
    out = mikt("transfer", "--ppo", "clip_range=0.1", "--ppo", "bootstrap_truncation=false", "--to", "hopper",
               "--method", "vpg", "--steps", 2048, "--eval-episodes", 1, "--json").stdout
    ppo = json.loads(mikt("inspect", json.loads(out)["run"], "--json").stdout)["card"]["config"]["ppo"]
    assert ppo["clip_range"] == 0.1 and ppo["bootstrap_truncation"] is False
    mikt("teacher", "train", "hopper", "--steps", 2048, "--ppo", "gamma=0.98")
    assert json.loads(mikt("inspect", "run2", "--json").stdout)["card"]["config"]["ppo"]["gamma"] == 0.98


@pytest.mark.parametrize("item, message", [
    ("clip_rang=0.1", "unknown PPO setting 'clip_rang'; the settings are: n_steps, num_envs"),
    ("clip_range=wide", "bad PPO setting: field 'clip_range'"),
    ("compile_loss=true", "unknown PPO setting 'compile_loss'"),  # --compile decides that
])
def test_a_bad_key_or_value_is_one_line_naming_what_is_valid(registry, item, message):
    out = mikt("transfer", "--ppo", item, "--to", "hopper", "--method", "vpg", "--steps", 2048, code=1).output
    assert message in out
    assert not (registry / "runs").exists() or not list((registry / "runs").iterdir())


def test_a_setting_given_twice_and_a_malformed_item_are_refused(registry):
    assert "given twice" in mikt("transfer", "--kl-coef", 0.1, "--ppo", "kl_coef=0.2", "--to", "hopper",
                                 "--method", "vpg", "--steps", 2048, code=1).output
    assert "expected KEY=VALUE" in mikt("transfer", "--ppo", "clip_range", "--to", "hopper", "--method", "vpg",
                                        code=2).output


def test_the_help_lists_every_setting():
    out = mikt("transfer", "--help").stdout
    assert "PPO settings (--ppo KEY=VALUE" in out and "bootstrap_truncation (default True)" in out


def test_a_grid_method_s_ppo_table_reaches_its_cells_and_a_changed_one_is_not_reused(registry, tmp_path):
    grid = tmp_path / "g.toml"
    body = ('name = "g"\nsteps = 2048\nseeds = [0]\neval_episodes = 1\nbaseline = "vpg"\n'
            '[[pairs]]\nfrom = ["x"]\nto = "hopper"\n[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    grid.write_text(body + "ppo = { clip_range = 0.1 }\n")
    mikt("study", grid, "--out", tmp_path / "out")
    assert json.loads((registry / "runs" / "run1" / "run.json").read_text())["config"]["ppo"]["clip_range"] == 0.1
    grid.write_text(body + "ppo = { clip_range = 0.3 }\n")
    out = mikt("study", grid, "--out", tmp_path / "out", code=1).output
    assert "trains with PPO clip_range = 0.1, the grid asks 0.3" in out
    grid.write_text(body + "ppo = { clip_rnge = 0.3 }\n")
    assert "unknown PPO setting 'clip_rnge'" in mikt("study", grid, "--out", tmp_path / "o2", code=1).output
