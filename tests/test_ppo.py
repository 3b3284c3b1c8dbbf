import numpy as np
import pytest
import torch

from miktcli.engine.nets import ObsNormalizer
from miktcli.engine.policies import GaussianActorCritic
from miktcli.engine.ppo import PPOConfig, PPOTrainer, compute_gae, flushing_denormals
from miktcli.envs import make_env
from miktcli.envs.spec import load_spec_file
from miktcli.envs.vector import SyncEnvs


def test_gae_against_a_hand_computed_case():
    g, lam = 0.9, 0.8
    rewards = np.array([[1.0], [2.0], [3.0], [4.0]])
    values = np.array([[0.5], [1.0], [1.5], [2.0]])
    # step 1 terminates; step 3 is cut by the time limit and bootstraps V(final obs) = 10
    next_values = np.array([[1.0], [123.0], [2.0], [10.0]])
    terminated = np.array([[0.0], [1.0], [0.0], [0.0]])
    dones = np.array([[0.0], [1.0], [0.0], [1.0]])
    adv, ret = compute_gae(rewards, values, next_values, terminated, dones, g, lam)
    d3 = 4.0 + g * 10.0 - 2.0
    d2 = 3.0 + g * 2.0 - 1.5
    d1 = 2.0 - 1.0
    d0 = 1.0 + g * 1.0 - 0.5
    expected = [d0 + g * lam * d1, d1, d2 + g * lam * d3, d3]
    assert adv[:, 0] == pytest.approx(expected)
    assert ret[:, 0] == pytest.approx(np.array(expected) + values[:, 0])


def trainer(env="hopper", steps=512, seed=0, **cfg):
    torch.manual_seed(seed)
    spec_env = make_env(env)
    agent = GaussianActorCritic(spec_env.observation_space.shape[0], spec_env.action_space.shape[0])
    config = PPOConfig(n_steps=256, minibatch_size=64, epochs=2, **cfg)
    return PPOTrainer(agent, lambda: make_env(env), config, steps, seed)


def test_ratio_is_one_on_the_first_minibatch_and_flat_views_hold():
    t = trainer()
    for m in t.run():
        assert m["first_minibatch_ratio_dev"] == 0.0
        assert m["steps"] <= 512
    assert t.flat.check_views()


def test_same_seed_same_metrics():
    a = [m for m in trainer(seed=3).run()]
    b = [m for m in trainer(seed=3).run()]
    keys = ("return_mean", "loss_policy", "loss_value", "approx_kl", "episodes")
    assert [[m[k] for k in keys] for m in a] == [[m[k] for k in keys] for m in b]
    c = [m for m in trainer(seed=4).run()]
    assert [m["loss_policy"] for m in a] != [m["loss_policy"] for m in c]


def test_training_improves_hopper_quickly():
    t = trainer(steps=8192)
    rows = list(t.run())
    assert rows[-1]["return_mean"] > rows[0]["return_mean"]


def test_autoreset_keeps_final_obs_and_no_dummy_transition(tmp_path):
    path = tmp_path / "short.toml"
    path.write_text('name = "short"\nfamily = "centipede"\nlegs = 8\nobs_dim = 181\nact_dim = 22\n'
                    "max_episode_steps = 5\n")
    spec = load_spec_file(path)
    envs = SyncEnvs([make_env(spec)], seed=2)
    for _ in range(5):
        res = envs.step(np.zeros((1, 22), np.float32))
    assert res.truncated[0] and not res.terminated[0]
    assert 0 in res.final_obs and res.finished[0][1] == 5
    assert not np.array_equal(res.final_obs[0], res.obs[0])  # the next obs is the new episode's first
    res = envs.step(np.zeros((1, 22), np.float32))
    assert res.rewards[0] != 0.0 and not res.final_obs  # a real transition, not a zero-reward dummy


def test_normalizer_frozen_and_round_trip(tmp_path):
    from safetensors.torch import load_file, save_file

    norm = ObsNormalizer(3)
    data = np.random.default_rng(0).normal(2.0, 3.0, size=(500, 3))
    for row in data[:250]:
        norm.update(row[None])
    norm.update(data[250:])
    assert norm.mean.numpy() == pytest.approx(data.mean(0))
    assert norm.var.numpy() == pytest.approx(data.var(0))
    save_file(dict(norm.state_dict()), tmp_path / "n.safetensors")
    other = ObsNormalizer(3)
    other.load_state_dict(load_file(tmp_path / "n.safetensors"))
    x = torch.tensor(data[:4], dtype=torch.float32)
    assert torch.equal(other(x), norm(x))
    other.frozen = True
    other.update(data * 100)
    assert torch.equal(other.mean, norm.mean)


def test_trainer_state_round_trip():
    t = trainer(steps=512)
    list(t.run())
    state, progress = t.state_tensors(), t.progress_state()
    u = trainer(steps=1024)
    u.load_state(state, progress)
    assert (u.iteration, u.global_step) == (t.iteration, t.global_step)
    for k, v in u.state_tensors().items():
        assert torch.equal(v, state[k]), k
    assert u.flat.check_views()
    assert len(list(u.run())) == 2  # continues to 1024 steps


def test_hand_written_gaussian_log_prob_and_kl_match_torch_distributions():
    from torch.distributions import Independent, Normal, kl_divergence

    from miktcli.engine.policies import gaussian_kl, gaussian_log_prob

    torch.manual_seed(0)
    mean, old_mean = torch.randn(32, 5), torch.randn(32, 5)
    log_std, old_log_std = 0.3 * torch.randn(5), 0.3 * torch.randn(5)
    actions = torch.randn(32, 5) * 2
    new = Independent(Normal(mean, log_std.exp()), 1)
    old = Independent(Normal(old_mean, old_log_std.exp()), 1)
    torch.testing.assert_close(gaussian_log_prob(actions, mean, log_std), new.log_prob(actions))
    torch.testing.assert_close(gaussian_kl(mean, log_std, old_mean, old_log_std), kl_divergence(new, old))



def subnormals(t):
    tiny = torch.finfo(torch.float32).tiny
    state = t.optimizer.state[t.flat.flat]
    return sum(int(((x != 0) & (x.abs() < tiny)).sum())
               for x in (t.flat.flat.data, state["exp_avg"], state["exp_avg_sq"]))


def test_an_iteration_flushes_the_subnormals_in_weights_and_adam_s_moments():
    t = trainer(steps=768)
    runs = t.run()
    next(runs)  # one update, so Adam has moments to plant into
    tiny = torch.finfo(torch.float32).tiny
    with torch.no_grad():
        t.agent.pi.head.weight[0].fill_(tiny / 8)
        state = t.optimizer.state[t.flat.flat]
        state["exp_avg"][:100].fill_(tiny / 8)
        state["exp_avg_sq"][:100].fill_(tiny / 8)
    assert subnormals(t) == t.agent.pi.head.weight.shape[1] + 200
    next(runs)
    assert subnormals(t) == 0


def test_subnormals_are_flushed_inside_the_update_only_and_old_cards_kept_them():
    tiny = torch.finfo(torch.float32).tiny
    x = torch.tensor(tiny)
    with flushing_denormals(True):
        assert float(x / 8) == 0.0
    assert float(x / 8) != 0.0  # the rollout and the physics keep IEEE arithmetic
    with flushing_denormals(False):
        assert float(x / 8) != 0.0
    assert PPOConfig().flush_denormal
    assert not PPOConfig.from_record({}).flush_denormal  # what runs before the setting did


def test_the_trainer_sets_torch_s_threads_as_its_config_records():
    torch.set_num_threads(2)  # as a notebook or a script might have left it
    try:
        t = trainer()
        assert torch.get_num_threads() == t.config.torch_threads == 1
    finally:
        torch.set_num_threads(1)
    assert PPOConfig.from_record({}).torch_threads == 1  # older cards trained with the CLI's one thread


def test_cat_s_value_loss_is_there_by_name_with_its_zero_target():
    t = trainer(value_loss="cat-zero-target")
    batch = t._values_and_targets(t.collect()[0])
    mb = batch.take(slice(0, 64))
    _, logs = t.loss(mb, t.agent.log_std.detach())
    with torch.no_grad():
        value = t.agent.value(mb.obs)
        clipped = mb.values + (value - mb.values).clamp(-0.2, 0.2)
        expected = 0.5 * torch.max(value.square(), (clipped - mb.returns).square()).mean()
    torch.testing.assert_close(logs["loss_value"], expected)
    assert PPOConfig().value_loss == "ppo2"


@pytest.mark.parametrize("lrs", [[3e-4] * 6, [3e-4, 2e-4, 1e-4, 5e-5, 1e-5, 0.0]])
def test_the_engine_s_adam_is_torch_s_fused_adam_bit_for_bit(lrs):
    from miktcli.engine.adam import FusedAdam

    gen = torch.Generator().manual_seed(0)
    ours, theirs = (torch.nn.Parameter(torch.randn(1000, generator=torch.Generator().manual_seed(1)))
                    for _ in range(2))
    mine = FusedAdam([ours], lr=lrs[0], eps=1e-5)
    reference = torch.optim.Adam([theirs], lr=lrs[0], eps=1e-5, fused=True)
    for lr in lrs:
        grad = torch.randn(1000, generator=gen) * 10 ** float(torch.randint(-6, 2, (), generator=gen))
        ours.grad, theirs.grad = grad.clone(), grad.clone()
        mine.lr = lr
        for group in reference.param_groups:
            group["lr"] = lr
        mine.step()
        reference.step()
        assert torch.equal(ours.data, theirs.data)
    for key, value in reference.state[theirs].items():
        assert torch.equal(mine.state_of(ours)[key], value), key


def test_a_trainer_resumes_adam_s_moments_and_step_count():
    t = trainer(steps=768)
    next(t.run())
    tensors = t.state_tensors()
    assert float(tensors["optim.step"]) == t.config.epochs * (t.config.n_steps * t.config.num_envs
                                                               // t.config.minibatch_size)
    other = trainer(steps=768, seed=1)
    other.load_state(tensors, t.progress_state())
    for key in ("step", "exp_avg", "exp_avg_sq"):
        assert torch.equal(other.optimizer.state_of(other.flat.flat)[key], tensors[f"optim.{key}"]), key
