"""No silent import assumptions: without --obs-stats the imported policy sees raw observations,
unclipped, as SB3 without VecNormalize did; what a file cannot tell (CleanRL's activation) is given or recorded as
assumed; a complex log_std is refused; one policy under two names is one teacher given twice."""

import io
import json
import zipfile

import numpy as np
import pytest
import torch

from helpers import FIXTURE, cleanrl_agent, fixture_with, mikt, sb3_actions
from miktcli.errors import MiktError
from miktcli.registry.teachers import load_teacher


def test_without_obs_stats_observations_reach_the_policy_unclipped(registry):
    r = mikt("teacher", "import", FIXTURE, "--env", "hopper", "--name", "raw")
    assert "obs_stats: none given: raw observations, not clipped" in r.output
    teacher = load_teacher(registry, "raw")
    assert teacher.card.obs_clip is None and teacher.card.imported_from["activation"] == "read from policy_kwargs"
    obs = np.random.default_rng(0).normal(size=(5, 11)) * 40  # far beyond ±10
    np.testing.assert_allclose(teacher.policy.act(torch.as_tensor(obs, dtype=torch.float32)).detach().numpy(),
                               sb3_actions(obs), rtol=1e-4, atol=1e-5)


def test_with_obs_stats_the_normaliser_clips_as_vecnormalize_does(registry, tmp_path):
    stats = tmp_path / "stats.json"
    stats.write_text(json.dumps({"mean": [0.0] * 11, "var": [1.0] * 11}))
    mikt("teacher", "import", FIXTURE, "--env", "hopper", "--name", "norm", "--obs-stats", stats)
    teacher = load_teacher(registry, "norm")
    assert teacher.card.obs_clip == 10.0 and teacher.policy.obs_normalizer.clip == 10.0


def test_cleanrl_activation_is_given_or_recorded_as_assumed(registry, tmp_path):
    path = tmp_path / "m.cleanrl_model"
    torch.save(cleanrl_agent(11, 3).state_dict(), path)
    r = mikt("teacher", "import", path, "--env", "hopper", "--name", "assumed")
    assert "activation: assumed: ppo_continuous_action.py's tanh" in r.output
    assert load_teacher(registry, "assumed").card.imported_from["activation"].startswith("assumed")
    mikt("teacher", "import", path, "--env", "hopper", "--name", "given", "--activation", "relu")
    card = load_teacher(registry, "given").card
    assert card.activation == "relu" and card.imported_from["activation"] == "given (--activation)"
    assert "unknown activation 'gelu'" in mikt("teacher", "import", path, "--env", "hopper", "--activation", "gelu",
                                               code=1).output


def test_an_sb3_activation_contradicting_the_file_is_refused(registry):
    r = mikt("teacher", "import", FIXTURE, "--env", "hopper", "--activation", "tanh", code=1)
    assert "--activation tanh contradicts the file" in r.output


def test_a_complex_log_std_is_refused(registry, tmp_path):
    with zipfile.ZipFile(FIXTURE) as z:
        sd = torch.load(io.BytesIO(z.read("policy.pth")), weights_only=True)
    sd["log_std"] = sd["log_std"].to(torch.complex64)
    buffer = io.BytesIO()
    torch.save(sd, buffer)
    path = fixture_with(tmp_path, "complex.zip", weights=buffer.getvalue())
    assert "tensor 'log_std' is torch.complex64" in mikt("teacher", "import", path, "--env", "hopper",
                                                          code=1).output


def test_one_policy_under_two_names_is_one_teacher_given_twice(registry):
    mikt("teacher", "import", FIXTURE, "--env", "hopper", "--name", "first")
    mikt("teacher", "import", FIXTURE, "--env", "hopper", "--name", "second")
    from miktcli.workflows.transfer import start_transfer

    with pytest.raises(MiktError, match=r"teachers first@v1 and second@v1 hold the same tensors"):
        start_transfer(registry, to="centipede-four", method="mikt", teacher_refs=["first", "second"], steps=2048,
                       seed=0, command="t")
    r = mikt("transfer", "--from", "first", "--from", "second", "--to", "centipede-four", code=1)
    assert "hold the same tensors" in r.output and not (registry / "runs").exists()
