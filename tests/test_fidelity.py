"""The engine matches the authors' ppo2 where it changes results: raw actions, and each loss term counted once."""

import gymnasium as gym
import numpy as np
import pytest
import torch

from miktcli.engine.episodes import run_episodes
from miktcli.engine.policies import GaussianActorCritic, gaussian_kl
from miktcli.engine.ppo import PPOConfig, PPOTrainer
from miktcli.envs import make_env
from miktcli.envs.vector import SyncEnvs
from miktcli.methods.mikt import MiktActorCritic, MiktConfig


class RecordingEnv(gym.Wrapper):
    """Remembers every action that reaches the env."""

    def __init__(self, env):
        super().__init__(env)
        self.seen: list[np.ndarray] = []

    def step(self, action):
        self.seen.append(np.array(action, copy=True))
        return self.env.step(action)


@pytest.mark.parametrize("clip", [False, True])
def test_actions_reach_the_env_raw_unless_clipping_is_asked(clip):
    env = RecordingEnv(make_env("centipede-four"))
    envs = SyncEnvs([env], seed=0, clip_actions=clip)
    big = np.full((1, env.action_space.shape[0]), 3.0, np.float32)
    envs.step(big)
    assert env.seen[-1].max() == (1.0 if clip else 3.0)


def test_training_sends_raw_gaussian_samples_by_default():
    torch.manual_seed(0)
    recorder: list[RecordingEnv] = []

    def make():
        recorder.append(RecordingEnv(make_env("centipede-four")))
        return recorder[-1]

    agent = GaussianActorCritic(97, 10)
    config = PPOConfig(n_steps=256, minibatch_size=64, epochs=1)
    assert config.clip_actions_for_env is False
    trainer = PPOTrainer(agent, make, config, 256, seed=0)
    trainer.collect()
    seen = np.abs(np.concatenate(recorder[0].seen))
    assert seen.max() > 1.5  # N(0, 1) samples: many fall outside [-1, 1] and reach the env as they are


def test_evaluation_clips_only_when_asked():
    env = RecordingEnv(make_env("centipede-four"))
    act = lambda obs: torch.full((1, 10), 2.5)  # noqa: E731
    run_episodes(act, env, episodes=1, seed=0)
    assert max(a.max() for a in env.seen) == 2.5
    env.seen.clear()
    run_episodes(act, env, episodes=1, seed=0, clip_actions=True)
    assert max(a.max() for a in env.seen) == 1.0


def test_records_from_before_the_option_keep_clipping():
    assert PPOConfig.from_record({}).clip_actions_for_env is True
    assert PPOConfig.from_record(PPOConfig().model_dump()).clip_actions_for_env is False


# --- each loss term counted exactly once ----------------------------------------------------------------


def minibatch(trainer: PPOTrainer):
    rollout, _ = trainer.collect()
    batch = trainer._values_and_targets(rollout)
    return batch.take(slice(0, 64))


def flat_grad(trainer: PPOTrainer, mb, old_log_std, **config) -> torch.Tensor:
    trainer.config = trainer.config.model_copy(update=config)
    loss, _ = trainer.loss(mb, old_log_std)
    trainer.flat.zero_grad()
    loss.backward()
    return trainer.flat.flat.grad.clone()


def perturb(agent) -> None:
    """Move the policy away from the one that collected the batch, so KL(pi || pi_old) has a gradient."""
    with torch.no_grad():
        for p in agent.pi.parameters():
            p.add_(0.05 * torch.randn_like(p))
        agent.log_std.add_(0.1)


def ppo_trainer(agent, env="centipede-four"):
    return PPOTrainer(agent, lambda: make_env(env), PPOConfig(n_steps=256, minibatch_size=64), 256, seed=0)


@pytest.mark.parametrize("coef", [0.05, 0.3])
def test_kl_gradient_is_its_coefficient_times_the_kl_gradient(coef):
    torch.manual_seed(0)
    trainer = ppo_trainer(GaussianActorCritic(97, 10))
    mb = minibatch(trainer)
    old_log_std = trainer.agent.log_std.detach().clone()
    perturb(trainer.agent)
    without = flat_grad(trainer, mb, old_log_std, kl_coef=0.0)
    with_kl = flat_grad(trainer, mb, old_log_std, kl_coef=coef)
    agent = trainer.agent
    kl = gaussian_kl(agent.action_mean(mb.obs), agent.log_std, mb.means, old_log_std).mean()
    trainer.flat.zero_grad()
    kl.backward()
    expected = coef * trainer.flat.flat.grad
    assert expected.abs().max() > 1e-4  # the check has teeth
    torch.testing.assert_close(with_kl - without, expected, rtol=1e-4, atol=1e-6)


def test_the_loss_is_the_sum_of_its_logged_weighted_terms_each_once():
    torch.manual_seed(0)
    teacher = GaussianActorCritic(97, 10)
    teacher.requires_grad_(False)
    agent = MiktActorCritic(97, 10, [teacher], MiktConfig(coupling_schedule="constant"))
    trainer = ppo_trainer(agent)
    trainer.config = trainer.config.model_copy(update={"kl_coef": 0.05, "ent_coef": 0.01})
    mb = minibatch(trainer)
    old_log_std = agent.log_std.detach().clone()
    perturb(agent)
    loss, logs = trainer.loss(mb, old_log_std)
    weighted = {"loss_kl", "loss_entropy", "loss_coupling", "loss_mi"}
    assert weighted <= set(logs)
    total = logs["loss_policy"] + trainer.config.vf_coef * logs["loss_value"] + sum(logs[k] for k in weighted)
    torch.testing.assert_close(loss.detach(), total)


@pytest.mark.parametrize("term,option", [("loss_mi", "mi_coef"), ("loss_coupling", "coupling_pi_coef")])
def test_each_mikt_term_adds_exactly_its_own_gradient(term, option):
    torch.manual_seed(0)
    teacher = GaussianActorCritic(97, 10)
    teacher.requires_grad_(False)
    agent = MiktActorCritic(97, 10, [teacher], MiktConfig(coupling_schedule="constant", coupling_vf_coef=0.0))
    trainer = ppo_trainer(agent)
    mb = minibatch(trainer)
    old_log_std = agent.log_std.detach().clone()
    full = flat_grad(trainer, mb, old_log_std)
    coef = getattr(agent.config, option)
    agent.config = agent.config.model_copy(update={option: 0.0})
    without = flat_grad(trainer, mb, old_log_std)
    agent.config = agent.config.model_copy(update={option: coef})
    _, _, extra = agent.evaluate_actions(mb.obs)
    trainer.flat.zero_grad()
    extra[term].backward()
    assert trainer.flat.flat.grad.abs().max() > 1e-5
    torch.testing.assert_close(full - without, trainer.flat.flat.grad, rtol=1e-4, atol=1e-6)


# --- the authors' lateral projection, as an option ----------------------------------------------------


def mikt_agent(lateral: str) -> MiktActorCritic:
    torch.manual_seed(0)
    teacher = GaussianActorCritic(97, 10)
    teacher.requires_grad_(False)
    return MiktActorCritic(139, 16, [teacher], MiktConfig(lateral=lateral, coupling_schedule="constant"))


def test_identity_laterals_have_no_matrix_and_projection_learns_one_per_layer():
    assert mikt_agent("identity").lateral_pi is None
    agent = mikt_agent("projection")
    weights = [u.weight for us in (*agent.lateral_pi, *agent.lateral_vf) for u in us]
    assert [w.shape for w in weights] == [(64, 64)] * 4
    assert all(u.bias is None for us in agent.lateral_pi for u in us)
    mean, value, extra = agent.evaluate_actions(torch.randn(16, 139))
    (mean.square().sum() + value.square().sum()).backward()
    assert all(w.grad is not None and w.grad.abs().sum() > 0 for w in weights)


def test_projection_by_the_identity_matrix_is_the_identity_option():
    plain, projected = mikt_agent("identity"), mikt_agent("projection")
    projected.load_state_dict(plain.state_dict(), strict=False)
    with torch.no_grad():
        for us in (*projected.lateral_pi, *projected.lateral_vf):
            for u in us:
                u.weight.copy_(torch.eye(64))
    obs = torch.randn(8, 139)
    torch.testing.assert_close(plain.action_mean(obs), projected.action_mean(obs))
    torch.testing.assert_close(plain.value(obs), projected.value(obs))
    with torch.no_grad():
        projected.lateral_pi[0][0].weight.mul_(2.0)
    assert not torch.allclose(plain.action_mean(obs), projected.action_mean(obs))


def test_a_diverging_simulation_is_counted_not_logged_to_the_working_directory(tmp_path, monkeypatch):
    from miktcli.envs.mujoco_warnings import last_mujoco_warning, mujoco_warning_count

    monkeypatch.chdir(tmp_path)
    env = make_env("centipede-four")
    env.reset(seed=0)
    before = mujoco_warning_count()
    env.unwrapped.data.qvel[0] = np.nan
    _, _, terminated, _, _ = env.step(np.zeros(10, np.float32))
    assert terminated
    assert mujoco_warning_count() == before + 1 and "unstable" in last_mujoco_warning()
    assert list(tmp_path.iterdir()) == []  # no MUJOCO_LOG.TXT
