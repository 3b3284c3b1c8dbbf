"""An env that fails while it runs: a spec whose kwargs break only at step time is one line naming
the spec, in training and in evaluation, never "internal error ... please report it"."""

import pytest

from helpers import mikt, spec_dir
from miktcli.errors import MiktError

BREAKS_AT_STEP = ('name = "badstep"\nfamily = "gymnasium"\nid = "Hopper-v5"\nobs_dim = 11\nact_dim = 3\n'
                  'max_episode_steps = 1000\n[kwargs]\nhealthy_z_range = "ab"\n')


def test_training_on_an_env_that_fails_in_step_names_its_spec(registry, tmp_path, monkeypatch):
    spec_dir(tmp_path, monkeypatch, badstep=BREAKS_AT_STEP)
    r = mikt("transfer", "--to", "badstep", "--method", "vpg", "--steps", 2048, code=1)
    assert "Error: environment 'badstep' failed in step: UFuncTypeError" in r.output
    assert "mikt envs show badstep" in r.output and "please report" not in r.output


def test_evaluating_on_an_env_that_fails_in_step_names_its_spec(tmp_path, monkeypatch):
    from miktcli.engine.policies import GaussianActorCritic
    from miktcli.workflows.evaluate import evaluation_summary

    spec_dir(tmp_path, monkeypatch, badstep=BREAKS_AT_STEP)
    with pytest.raises(MiktError, match="environment 'badstep' failed in step"):
        evaluation_summary(GaussianActorCritic(11, 3, [8], [8], "tanh"), "badstep", 1, 0, False)
