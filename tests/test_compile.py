"""`--compile` (PPOConfig.compile_loss): the same loss and gradient as the eager engine, no recompiling as the
coupling ramp moves, and a failed compile is a one-line error rather than a silent eager fallback."""

import shutil

import pytest
import torch
import torch._dynamo

from miktcli.engine.policies import GaussianActorCritic
from miktcli.engine.ppo import PPOConfig, PPOTrainer
from miktcli.envs import make_env
from miktcli.errors import MiktError
from miktcli.methods.mikt import MiktActorCritic, MiktConfig

needs_compiler = pytest.mark.skipif(shutil.which("g++") is None and shutil.which("clang++") is None,
                                    reason="torch.compile on CPU needs a C++ compiler")


def mikt_trainer(compile_loss: bool) -> PPOTrainer:
    torch.manual_seed(0)
    teacher = GaussianActorCritic(97, 10)
    teacher.requires_grad_(False)
    agent = MiktActorCritic(97, 10, [teacher], MiktConfig())  # three-phase: the ramp is a run-time input
    config = PPOConfig(n_steps=256, minibatch_size=64, kl_coef=0.05, compile_loss=compile_loss)
    return PPOTrainer(agent, lambda: make_env("centipede-four"), config, 256, seed=0)


def loss_and_grad(trainer: PPOTrainer, mb, old_log_std):
    loss, logs = trainer._minibatch_loss(mb, old_log_std)
    trainer.flat.zero_grad()
    loss.backward()
    return loss.detach(), {k: v.detach() for k, v in logs.items()}, trainer.flat.flat.grad.clone()


@pytest.mark.slow
@needs_compiler
def test_compiled_loss_equals_the_eager_loss_and_gradient_and_does_not_recompile_along_the_ramp():
    eager, fast = mikt_trainer(False), mikt_trainer(True)
    fast.agent.load_state_dict(eager.agent.state_dict())
    rollout, _ = eager.collect()
    mb = eager._values_and_targets(rollout).take(slice(0, 64))
    old_log_std = eager.agent.log_std.detach().clone()
    for progress in (0.5, 0.6):  # both on the ramp: a new coupling weight, the same compiled graph
        for trainer in (eager, fast):
            trainer.agent.set_progress(progress)
        expected = loss_and_grad(eager, mb, old_log_std)
        with torch._dynamo.config.patch(error_on_recompile=progress > 0.5):
            got = loss_and_grad(fast, mb, old_log_std)
        assert float(got[1]["loss_coupling"]) > 0
        torch.testing.assert_close(got[0], expected[0], rtol=1e-5, atol=1e-6)
        assert got[1].keys() == expected[1].keys()
        for key in expected[1]:
            torch.testing.assert_close(got[1][key], expected[1][key], rtol=1e-4, atol=1e-5)
        torch.testing.assert_close(got[2], expected[2], rtol=1e-4, atol=1e-6)


def test_a_failed_compile_is_an_error_naming_the_option(monkeypatch):
    def broken(fn, **kwargs):
        def call(*args):
            raise torch._dynamo.exc.TorchDynamoException("InvalidCxxCompiler: no working C++ compiler found")
        return call

    monkeypatch.setattr(torch, "compile", broken)
    trainer = mikt_trainer(True)
    with pytest.raises(MiktError, match=r"compile_loss: torch.compile failed \(InvalidCxxCompiler.*--compile"):
        next(trainer.run())


@pytest.mark.slow
@needs_compiler
def test_past_the_recompile_limit_is_an_error_not_a_silent_eager_fallback():
    def vpg_trainer(env: str, obs_dim: int, act_dim: int) -> PPOTrainer:
        config = PPOConfig(n_steps=128, minibatch_size=64, epochs=1, compile_loss=True)
        return PPOTrainer(GaussianActorCritic(obs_dim, act_dim), lambda: make_env(env), config, 128, seed=0)

    torch._dynamo.reset()  # forget the graphs earlier tests compiled
    first = vpg_trainer("hopper", 11, 3)
    # Set and put back by hand: monkeypatch's undo deletes the attribute (it is not in the module's __dict__),
    # and a deleted dynamo setting is hidden, which broke every later compile in the same test process.
    limit = torch._dynamo.config.recompile_limit
    try:
        torch._dynamo.config.recompile_limit = 1
        next(first.run())  # one graph: within the limit
        second = vpg_trainer("centipede-four", 97, 10)  # other shapes: a second graph of the same function
        torch._dynamo.config.recompile_limit = 1  # `compiled` raised it for the new trainer; lower it again
        with pytest.raises(MiktError, match="compile_loss: torch.compile failed"):
            next(second.run())
    finally:
        torch._dynamo.config.recompile_limit = limit


def test_auto_compiles_only_runs_long_enough_and_only_with_a_compiler(monkeypatch):
    from miktcli.engine import compile_choice
    from miktcli.engine.compile_choice import AUTO_MIN_STEPS, decide_compile

    assert decide_compile(True, 2048) == (True, "on: asked (--compile)")
    assert decide_compile(False, 2_000_000) == (False, "off: asked (--no-compile)")
    on, why = decide_compile(None, AUTO_MIN_STEPS - 1)
    assert not on and why.startswith("auto: off") and "below" in why
    monkeypatch.setattr(compile_choice, "cxx_compiler", lambda: "/usr/bin/g++")
    assert decide_compile(None, 2_000_000) == (True, "auto: on, 2,000,000 steps (compiling pays from 500,000)")
    monkeypatch.setattr(compile_choice, "cxx_compiler", lambda: None)
    on, why = decide_compile(None, 2_000_000)
    assert not on and "no C++ compiler found" in why  # off, and the card says why


def test_the_card_records_the_choice_and_its_reason(registry):
    from typer.testing import CliRunner

    from miktcli.cli.app import app
    from miktcli.registry.runs import open_run

    result = CliRunner().invoke(app, ["teacher", "train", "hopper", "--steps", "2048", "--name", "h",
                                      "--ppo", "gradients=autograd"])  # by hand is the default (test_by_hand)
    assert result.exit_code == 0, result.output
    assert "update: eager (auto: off, 2,048 steps is below 500,000" in result.output
    ppo = open_run(registry, "run1").card.config.ppo
    assert ppo.compile_loss is False and ppo.compile_reason.startswith("auto: off")
    result = CliRunner().invoke(app, ["transfer", "--from", "h", "--to", "centipede-four", "--steps", "2048",
                                      "--no-compile", "--eval-episodes", "1"])
    assert result.exit_code == 0, result.output
    ppo = open_run(registry, "run2").card.config.ppo
    assert ppo.compile_loss is False and ppo.compile_reason == "off: asked (--no-compile)"
