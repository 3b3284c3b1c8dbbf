"""The by-hand update (PPOConfig.gradients = "by-hand") against autograd: the same loss logs and gradients
to float rounding, for every loss option, and the guards around it."""

import json

import pytest
import torch

from helpers import mikt, runs
from miktcli.engine.by_hand import HandGradients, unsupported
from miktcli.engine.policies import GaussianActorCritic, gaussian_log_prob
from miktcli.engine.ppo import Minibatch, PPOConfig, PPOTrainer
from miktcli.envs import make_env
from miktcli.errors import MiktError
from miktcli.methods.mikt import MiktActorCritic, MiktConfig

ROWS, OBS, ACT = 64, 11, 3


def minibatch(agent: GaussianActorCritic, gen: torch.Generator) -> Minibatch:
    """Near the agent's own policy and value, so that some ratios and value changes clip and some do not."""
    def randn(*shape):
        return torch.randn(*shape, generator=gen)

    obs = randn(ROWS, OBS)
    with torch.no_grad():
        mean, value = agent.pi(obs), agent.value(obs)
        actions = mean + randn(ROWS, ACT) * agent.log_std.exp()
        log_probs = gaussian_log_prob(actions, mean, agent.log_std) + randn(ROWS) * 0.1
        values = value + randn(ROWS) * 0.2
    return Minibatch(obs=obs, actions=actions, log_probs=log_probs, means=mean + randn(ROWS, ACT) * 0.05,
                     advantages=randn(ROWS), returns=values + randn(ROWS) * 0.5, values=values)


def trainer_for(agent: GaussianActorCritic, **settings) -> PPOTrainer:
    config = PPOConfig(n_steps=64, **settings)
    return PPOTrainer(agent, lambda: make_env("hopper"), config, 64, 0)


def agent_with_moved_weights(activation: str = "tanh") -> GaussianActorCritic:
    torch.manual_seed(1)
    agent = GaussianActorCritic(OBS, ACT, activation=activation)
    with torch.no_grad():  # away from the initial weights, so that ratios move and some clip
        for p in agent.parameters():
            p.add_(torch.randn_like(p) * 0.3)
        agent.vf.head.weight.mul_(0.2)
    return agent


def autograd_and_hand(settings: dict, activation: str = "tanh"):
    agent = agent_with_moved_weights(activation)
    trainer = trainer_for(agent, **{k: v for k, v in settings.items() if k != "log_std"})
    with torch.no_grad():
        agent.log_std.copy_(torch.tensor([-0.4, 0.1, 0.3]))  # the trainer set log_std_init
    mb = minibatch(agent, torch.Generator().manual_seed(2))
    old_log_std = agent.log_std.detach() - 0.05
    loss, logs = trainer.loss(mb, old_log_std)
    trainer.flat.zero_grad()
    loss.backward()
    want = trainer.flat.flat.grad.clone()
    trainer.flat.flat.grad.fill_(float("nan"))  # every gradient must be written, none left over
    hand_logs = HandGradients(agent, trainer.config)(mb, old_log_std)
    return logs, want, hand_logs, trainer.flat.flat.grad.clone()


SETTINGS = [
    {},
    {"clip_range": 0.05},
    {"normalize_advantage": False},
    {"clip_value_loss": False},
    {"value_loss": "sb3"},
    {"value_loss": "sb3", "clip_value_loss": False},
    {"value_loss": "cat-zero-target"},
    {"value_loss": "cat-zero-target", "clip_value_loss": False},
    {"ent_coef": 0.01},
    {"kl_coef": 0.05},
    {"kl_coef": 1.0, "ent_coef": 0.1, "vf_coef": 1.0, "clip_range": 0.1},
]


@pytest.mark.parametrize("settings", SETTINGS, ids=[",".join(f"{k}={v}" for k, v in s.items()) or "default"
                                                    for s in SETTINGS])
def test_by_hand_gives_autograd_s_gradient_and_logs(settings):
    logs, want, hand_logs, got = autograd_and_hand(settings)
    assert not torch.isnan(got).any()
    assert want.abs().max() > 0.01  # a gradient worth comparing
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-6)
    assert list(hand_logs) == list(logs)
    for key in logs:
        torch.testing.assert_close(hand_logs[key], logs[key], rtol=1e-6, atol=1e-7)


def test_the_comparison_clips_some_samples():
    """The cases above mean something only if both branches of the clipped surrogate and the clipped value
    loss occur."""
    logs, *_ = autograd_and_hand({"clip_range": 0.05})
    assert 0.1 < float(logs["clipfrac"]) < 0.9
    agent = agent_with_moved_weights()
    mb = minibatch(agent, torch.Generator().manual_seed(2))
    with torch.no_grad():
        clipped = ((agent.value(mb.obs) - mb.values).abs() > 0.2).float().mean()
    assert 0.1 < float(clipped) < 0.9  # and the value clip at the default range


def test_relu_networks_have_their_gradient_by_hand_too():
    _, want, _, got = autograd_and_hand({}, activation="relu")
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-6)


def test_a_by_hand_run_learns_and_records_its_path():
    torch.manual_seed(0)
    env = make_env("hopper")
    agent = GaussianActorCritic(env.observation_space.shape[0], env.action_space.shape[0])
    trainer = PPOTrainer(agent, lambda: make_env("hopper"), PPOConfig(n_steps=256, epochs=2,
                                                                      gradients="by-hand"), 1024, 0)
    rows = list(trainer.run())
    assert len(rows) == 4 and all(r["grad_norm"] > 0 for r in rows)
    assert trainer.flat.check_views()
    assert trainer.config.model_dump()["gradients"] == "by-hand"


def test_mikt_and_frozen_agents_are_refused_by_name():
    teacher = GaussianActorCritic(OBS, ACT).requires_grad_(False)
    mikt = MiktActorCritic(OBS, ACT, [teacher], MiktConfig())
    assert "MiktActorCritic" in unsupported(mikt)
    assert "frozen" in unsupported(GaussianActorCritic(OBS, ACT).requires_grad_(False))
    with pytest.raises(MiktError, match="gradients=by-hand: MiktActorCritic"):
        PPOTrainer(mikt, lambda: make_env("hopper"), PPOConfig(n_steps=64, gradients="by-hand"), 64, 0)


def test_by_hand_and_a_compiled_loss_exclude_each_other():
    with pytest.raises(MiktError, match="no loss to compile"):
        trainer_for(GaussianActorCritic(OBS, ACT), gradients="by-hand", compile_loss=True)


def card_ppo(run_id: str) -> dict:
    return json.loads(mikt("inspect", run_id, "--json").stdout)["card"]["config"]["ppo"]


def test_which_runs_have_their_gradient_by_hand_by_default(teacher):
    mikt("teacher", "train", "hopper", "--steps", 1024, "--name", "h")  # run2 (run1 trained tiny)
    assert card_ppo("run2")["gradients"] == "by-hand"
    assert card_ppo("run2")["compile_reason"].startswith("off: the gradient is by hand")
    mikt("teacher", "train", "hopper", "--steps", 1024, "--name", "h2", "--no-compile")  # autograd's eager path
    assert card_ppo("run3")["gradients"] == "autograd"
    mikt("transfer", "--to", "centipede-four", "--method", "vpg", "--steps", 1024,
         "--eval-episodes", 1)
    assert card_ppo("run4")["gradients"] == "by-hand"
    mikt("transfer", "--from", "tiny", "--to", "centipede-four", "--steps", 1024, "--eval-episodes", 1)
    assert card_ppo("run5")["gradients"] == "autograd"  # MIKT's mixed network


def test_impossible_by_hand_requests_are_one_line_errors(teacher):
    out = mikt("transfer", "--from", "tiny", "--to", "centipede-four", "--steps", 1024, "--ppo",
               "gradients=by-hand", code=1).output
    assert "only the plain actor-critic" in out
    out = mikt("transfer", "--to", "centipede-four", "--method", "vpg", "--seeds", "0-1",
               "--steps", 1024, "--ppo", "gradients=by-hand", code=1).output
    assert "one seed at a time" in out
    out = mikt("teacher", "train", "hopper", "--steps", 1024, "--ppo", "gradients=by-hand", "--compile",
               code=1).output
    assert "no loss to compile" in out
    assert len(runs(teacher.parents[2])) == 1  # none of them made a run folder


def test_seeds_together_keep_autograd(teacher):
    mikt("transfer", "--to", "centipede-four", "--method", "vpg", "--seeds", "0-1",
         "--steps", 1024, "--eval-episodes", 1)
    assert card_ppo("run2")["gradients"] == card_ppo("run3")["gradients"] == "autograd"


def test_a_by_hand_run_keeps_its_path_on_resume(teacher, ctrl_c_at_second_update):
    mikt("teacher", "train", "hopper", "--steps", 6144, "--name", "h", code=1)  # interrupted at 2,048
    ctrl_c_at_second_update()
    out = mikt("teacher", "train", "--resume", "run2", "--compile", code=1).output
    assert "computes its gradient by hand" in out
    mikt("teacher", "train", "--resume", "run2")
    assert card_ppo("run2")["gradients"] == "by-hand"


def test_a_study_keeps_autograd_unless_its_grid_asks(registry):
    """A grid's compile_loss (off unless set) picks autograd's eager path, so the committed studies keep
    reproducing; a method's `ppo = { gradients = "by-hand" }` turns the faster path on."""
    from miktcli.studies.grid import Grid
    from miktcli.studies.study import Study

    grid = Grid.model_validate({"name": "g", "steps": 2048, "seeds": [0], "eval_episodes": 1, "methods": [
        {"name": "vpg", "method": "vpg"}, {"name": "vpg-by-hand", "method": "vpg", "ppo": {"gradients": "by-hand"}}],
        "pairs": [{"from": ["x"], "to": "centipede-four"}]})
    cells = Study(grid, registry.parent / "out", registry).prepare("test")
    assert sorted(run.card.config.ppo.gradients for _, run in cells) == ["autograd", "by-hand"]
