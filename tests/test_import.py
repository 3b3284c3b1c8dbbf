"""Teachers trained elsewhere: SB3 zips and CleanRL models imported without unpickling anything."""

import base64
import io
import json
import pickle
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from helpers import FIXTURE, cleanrl_agent, fixture_with, mikt, runner, sb3_actions
from miktcli.cli.app import app


@pytest.mark.slow
def test_an_sb3_zip_imports_evaluates_and_transfers(registry, tmp_path):
    stats = tmp_path / "stats.json"
    stats.write_text(json.dumps({"mean": [0.0] * 11, "var": [1.0] * 11}))
    r = mikt("teacher", "import", FIXTURE, "--env", "hopper", "--name", "sb3hop", "--obs-stats", stats)
    assert r.stdout.strip() == "sb3hop@v1" and "relu" in r.output
    card = json.loads(mikt("teacher", "show", "sb3hop", "--json").stdout)
    assert card["activation"] == "relu" and card["pi_hidden"] == [8, 8] and card["obs_dim"] == 11
    assert card["imported_from"]["format"] == "sb3" and card["clip_actions_for_env"] is True
    from miktcli.registry.teachers import load_teacher

    teacher = load_teacher(registry, "sb3hop")
    obs = np.random.default_rng(0).normal(size=(5, 11)).clip(-9, 9)
    np.testing.assert_allclose(teacher.policy.act(torch.as_tensor(obs, dtype=torch.float32)).detach().numpy(),
                               sb3_actions(obs), rtol=1e-5, atol=1e-6)
    assert json.loads(mikt("eval", "sb3hop", "--episodes", 1, "--json").stdout)["episodes"] == 1
    for method in ("mikt", "mlpp"):
        r = mikt("transfer", "--from", "sb3hop", "--to", "centipede-four", "--method", method, "--steps", 2048,
                 "--eval-episodes", 1, "--json")
        assert json.loads(r.stdout)["eval_without_teacher"]["episodes"] == 1
    assert "relu" in mikt("inspect", "sb3hop").stdout


def test_a_dimension_mismatch_names_both_values(registry):
    r = mikt("teacher", "import", FIXTURE, "--env", "ant", code=1)
    assert "reads obs 11 and acts 3; environment 'ant' has obs 111 / act 8" in r.output


class Trap:
    """Unpickling this creates a file: proof that code ran."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


def booby_trapped(tmp_path, marker, trap_weights: bool) -> Path:
    payload = base64.b64encode(pickle.dumps(Trap(str(marker)))).decode()
    out = tmp_path / ("trap-weights.zip" if trap_weights else "trap-data.zip")
    with zipfile.ZipFile(FIXTURE) as src, zipfile.ZipFile(out, "w") as dst:
        for item in src.namelist():
            content = src.read(item)
            if item == "data":
                data = json.loads(content)
                data["policy_kwargs"][":serialized:"] = payload
                data["observation_space"][":serialized:"] = payload
                content = json.dumps(data).encode()
            if item == "policy.pth" and trap_weights:
                content = pickle.dumps(Trap(str(marker)))
            dst.writestr(item, content)
    return out


def test_booby_trapped_pickles_are_never_executed(registry, tmp_path):
    marker = tmp_path / "pwned"
    r = mikt("teacher", "import", booby_trapped(tmp_path, marker, False), "--env", "hopper", "--name", "t1")
    assert r.stdout.strip() == "t1@v1"  # the serialized entries were never touched
    assert not marker.exists()
    r = mikt("teacher", "import", booby_trapped(tmp_path, marker, True), "--env", "hopper", "--name", "t2", code=1)
    assert "refused without unpickling" in r.output
    assert not marker.exists()


def test_a_cleanrl_model_imports_and_acts_the_same(registry, tmp_path):
    torch.manual_seed(0)
    agent = cleanrl_agent(97, 10)
    path = tmp_path / "ppo_continuous_action.cleanrl_model"
    torch.save(agent.state_dict(), path)
    stats = tmp_path / "stats.json"
    stats.write_text(json.dumps({"mean": [0.5] * 97, "var": [4.0] * 97, "count": 1000}))
    assert mikt("teacher", "import", path, "--env", "centipede-four", "--obs-stats", stats).stdout.strip() == \
        "centipede-four@v1"
    from miktcli.registry.teachers import load_teacher

    teacher = load_teacher(registry, "centipede-four")
    obs = torch.randn(4, 97)
    expected = agent.actor_mean(((obs.double() - 0.5) / np.sqrt(4.0 + 1e-8)).float())
    torch.testing.assert_close(teacher.policy.act(obs), expected, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(teacher.policy.log_std, torch.full((10,), -0.5))


@pytest.mark.parametrize("case,message", [
    ("shared", "share a trunk"), ("cnn", "features extractor has parameters"), ("junk", "not a readable zip"),
])
def test_unsupported_shapes_are_refused_clearly(registry, tmp_path, case, message):
    path = tmp_path / f"{case}.zip"
    if case == "junk":
        path.write_bytes(b"not a zip")
    else:
        with zipfile.ZipFile(FIXTURE) as z:
            sd = torch.load(io.BytesIO(z.read("policy.pth")), weights_only=True)
            extra = "mlp_extractor.shared_net.0.weight" if case == "shared" else "features_extractor.cnn.0.weight"
            sd[extra] = torch.zeros(8, 11)
            buffer = io.BytesIO()
            torch.save(sd, buffer)
            with zipfile.ZipFile(path, "w") as out:
                out.writestr("data", z.read("data"))
                out.writestr("policy.pth", buffer.getvalue())
    assert message in mikt("teacher", "import", path, "--env", "hopper", code=1).output


@pytest.mark.parametrize("activation", ["LeakyReLU", "ReLU6", "Tanhshrink"])
def test_activations_that_merely_contain_relu_or_tanh_are_refused(registry, tmp_path, activation):
    with zipfile.ZipFile(FIXTURE) as z:
        data = json.loads(z.read("data"))
    data["policy_kwargs"]["activation_fn"] = f"<class 'torch.nn.modules.activation.{activation}'>"
    path = fixture_with(tmp_path, "a.zip", data=json.dumps(data))
    assert "is not supported" in mikt("teacher", "import", path, "--env", "hopper", code=1).output


def test_damaged_archives_and_statistics_are_one_line_errors(registry, tmp_path):
    path = fixture_with(tmp_path, "deflated.zip", compress=zipfile.ZIP_DEFLATED)
    raw = bytearray(path.read_bytes())
    start = raw.index(b"policy.pth") + 40  # inside the compressed weights
    raw[start:start + 64] = bytes(64)
    path.write_bytes(bytes(raw))
    r = mikt("teacher", "import", path, "--env", "hopper", code=1)
    assert "not a readable zip" in r.output or "not a plain state dict" in r.output
    assert "internal error" not in r.output
    path = fixture_with(tmp_path, "deep.zip", data="[" * 100_000)
    assert "not JSON" in mikt("teacher", "import", path, "--env", "hopper", code=1).output
    stats = tmp_path / "stats.json"
    for body, message in (({"mean": [0] * 11, "var": [1] * 11, "count": float("nan")}, "'count' must be"),
                          ({"mean": [[0] * 11], "var": [[1] * 11]}, "flat lists of 11 numbers"),
                          ({"mean": [10 ** 400] + [0] * 10, "var": [1] * 11}, "lists of numbers")):
        stats.write_text(json.dumps(body))
        assert message in mikt("teacher", "import", FIXTURE, "--env", "hopper", "--obs-stats", stats, code=1).output
    assert not (registry / "teachers").exists()


def test_a_cleanrl_actor_without_a_hidden_layer_is_refused(registry, tmp_path):
    agent = cleanrl_agent(11, 3)
    state = {k: v for k, v in agent.state_dict().items() if not k.startswith("actor_mean.") or k.startswith(
        "actor_mean.4.")}
    path = tmp_path / "m.cleanrl_model"
    torch.save(state, path)
    assert "at least one hidden layer" in mikt("teacher", "import", path, "--env", "hopper", code=1).output


def test_an_import_that_shadows_a_teacher_says_so(registry):
    assert runner.invoke(app, ["teacher", "train", "hopper", "--steps", "2048"]).exit_code == 0  # hopper@v1
    r = runner.invoke(app, ["teacher", "import", str(FIXTURE), "--env", "hopper"])  # the name defaults to the env
    assert r.exit_code == 1 and "teacher 'hopper' exists already (hopper@v1" in r.output  # never silently
    r = runner.invoke(app, ["teacher", "import", str(FIXTURE), "--env", "hopper", "--name", "hopper"])  # on purpose
    assert r.exit_code == 0 and r.stdout.strip() == "hopper@v2", r.output
    assert ("warning: hopper@v2 (imported from sb3) is now what `hopper` means, in place of hopper@v1 "
            "(trained by mikt, 2,048 steps)") in r.output
    assert "name hopper@v1 to keep it, or import under another --name" in r.output
    r = runner.invoke(app, ["teacher", "import", str(FIXTURE), "--env", "hopper", "--name", "sb3hop"])
    assert r.exit_code == 0 and "warning" not in r.output  # a new name shadows nothing
