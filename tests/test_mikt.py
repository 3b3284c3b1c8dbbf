import math

import pytest
import torch

from miktcli.engine.policies import GaussianActorCritic
from miktcli.errors import MiktError
from miktcli.methods.mikt import MiktActorCritic, MiktConfig, initial_student_weight
from miktcli.methods.mlpp import mlpp_from_teacher
from miktcli.workflows.transfer import check_teachers


def frozen_teacher(obs_dim, act_dim, hidden=(64, 64)):
    t = GaussianActorCritic(obs_dim, act_dim, hidden, hidden)
    t.requires_grad_(False)
    return t


def groups(agent):
    return {
        "theta": list(agent.pi.parameters()) + [agent.log_std], "psi": list(agent.vf.parameters()),
        "phi": list(agent.encoders.parameters()), "omega": list(agent.decoders.parameters()),
        "p": [agent.mix_logits_pi, agent.mix_logits_vf], "teacher": list(agent.teachers.parameters()),
    }


def reached(agent, loss):
    agent.zero_grad(set_to_none=True)
    loss.backward()
    return {name: any(p.grad is not None and p.grad.abs().sum() > 0 for p in ps)
            for name, ps in groups(agent).items()}


@pytest.fixture()
def agent():
    torch.manual_seed(0)
    return MiktActorCritic(139, 16, [frozen_teacher(97, 10)], MiktConfig(coupling_schedule="constant"))


def ppo_like_loss(mean, value, agent):
    return mean.square().sum() + value.square().sum() + agent.log_std.sum()


def test_gradient_flow_per_parameter_group_as_algorithm_1(agent):
    obs = torch.randn(32, 139)
    mean, value, extra = agent.evaluate_actions(obs)
    assert set(extra) == {"loss_coupling", "loss_mi"}
    assert reached(agent, ppo_like_loss(mean, value, agent)) == {
        "theta": True, "psi": True, "phi": True, "omega": False, "p": True, "teacher": False}
    _, _, extra = agent.evaluate_actions(obs)
    assert reached(agent, extra["loss_mi"]) == {
        "theta": False, "psi": False, "phi": True, "omega": True, "p": False, "teacher": False}
    _, _, extra = agent.evaluate_actions(obs)
    assert reached(agent, extra["loss_coupling"]) == {
        "theta": False, "psi": False, "phi": False, "omega": False, "p": True, "teacher": False}


def test_without_rl_gradients_the_encoder_learns_from_mi_only():
    torch.manual_seed(0)
    agent = MiktActorCritic(139, 16, [frozen_teacher(97, 10)], MiktConfig(rl_encoder_grad=False))
    mean, value, extra = agent.evaluate_actions(torch.randn(8, 139))
    assert not reached(agent, ppo_like_loss(mean, value, agent))["phi"]
    mean, value, extra = agent.evaluate_actions(torch.randn(8, 139))
    assert reached(agent, extra["loss_mi"])["phi"]


def test_without_mi_there_is_no_mi_loss():
    agent = MiktActorCritic(139, 16, [frozen_teacher(97, 10)], MiktConfig(mi=False))
    assert "loss_mi" not in agent.evaluate_actions(torch.randn(4, 139))[2]


def test_initial_student_weight(agent):
    assert initial_student_weight() == pytest.approx(0.4725, abs=1e-4)
    p_pi, p_vf = agent.mixing_weights()
    assert torch.allclose(p_pi[:, 0], torch.tensor(0.4725), atol=1e-4)
    assert torch.allclose(p_vf[:, 0], torch.tensor(0.4725), atol=1e-4)


def test_with_p_equal_one_the_student_is_exactly_a_plain_mlp(agent):
    with torch.no_grad():
        agent.mix_logits_pi[:, 0], agent.mix_logits_pi[:, 1] = 100.0, -100.0
        agent.mix_logits_vf[:, 0], agent.mix_logits_vf[:, 1] = 100.0, -100.0
    obs = torch.randn(16, 139)
    plain = agent.student_only()
    assert torch.equal(agent.action_mean(obs), plain.action_mean(obs))
    assert torch.equal(agent.value(obs), plain.value(obs))


def test_two_teachers_of_different_state_dims_get_encoders_of_their_widths():
    agent = MiktActorCritic(181, 22, [frozen_teacher(97, 10), frozen_teacher(11, 3)], MiktConfig())
    assert [e.head.out_features for e in agent.encoders] == [97, 11]
    assert agent.mix_logits_pi.shape == (2, 3)
    mean, value, _ = agent.evaluate_actions(torch.randn(5, 181))
    assert mean.shape == (5, 22) and value.shape == (5,)


def test_a_teacher_with_the_targets_own_spaces_is_fine():
    agent = MiktActorCritic(97, 10, [frozen_teacher(97, 10)], MiktConfig())
    assert agent.evaluate_actions(torch.randn(3, 97))[0].shape == (3, 10)


def test_three_phase_schedule():
    agent = MiktActorCritic(97, 10, [frozen_teacher(97, 10)], MiktConfig())
    agent.set_progress(0.2)
    assert agent.teacher_active and agent.coupling_scale == 0.0
    assert "loss_coupling" not in agent.evaluate_actions(torch.randn(2, 97))[2]
    agent.set_progress(0.675)
    assert agent.coupling_scale == pytest.approx(0.5)
    agent.set_progress(0.95)
    assert not agent.teacher_active
    assert agent.evaluate_actions(torch.randn(2, 97))[2] == {}
    assert agent.diagnostics()["p_pi_0"] == 1.0


class FakeTeacher:
    def __init__(self, name, obs_dim, hidden=(64, 64)):
        from types import SimpleNamespace

        self.card = SimpleNamespace(ref=f"{name}@v1", obs_dim=obs_dim, pi_hidden=list(hidden),
                                    vf_hidden=list(hidden))


def test_width_and_hidden_checks_fail_before_training():
    four, hop = FakeTeacher("centipede-four", 97), FakeTeacher("hopper", 11)
    assert check_teachers([four, hop], [97, 11], None) == ([64, 64], [64, 64])
    with pytest.raises(MiktError, match=r"teacher 'hopper@v1': state dim 11 \(from its card\), encoder width 12 req"):
        check_teachers([four, hop], [97, 12], None)
    with pytest.raises(MiktError, match=r"teacher 'centipede-four@v1': hidden sizes \[64, 64\] \(policy\)"):
        check_teachers([four], None, [32, 32])
    with pytest.raises(MiktError, match="teacher 'small@v1': hidden sizes"):
        check_teachers([four, FakeTeacher("small", 11, (32, 32))], None, None)


def test_mlpp_copies_the_middle_stack():
    teacher = frozen_teacher(97, 10)
    student = mlpp_from_teacher(teacher, 181, 22)
    for net, src in ((student.pi, teacher.pi), (student.vf, teacher.vf)):
        assert torch.equal(net.hidden[1].weight, src.hidden[1].weight)
        assert torch.equal(net.hidden[1].bias, src.hidden[1].bias)
        assert net.hidden[0].in_features == 181
    assert student.pi.head.out_features == 22
    assert all(p.requires_grad for p in student.parameters())


@pytest.mark.parametrize("teachers", [1, 2, 3])
@pytest.mark.parametrize("lateral", ["identity", "projection"])
@pytest.mark.parametrize("mixing", ["per-teacher", "shared"])
def test_the_rollout_forward_gives_the_same_bits_as_action_mean(teachers, lateral, mixing):
    torch.manual_seed(teachers)
    dims = [(97, 10), (139, 16), (11, 3)][:teachers]
    agent = MiktActorCritic(181, 22, [frozen_teacher(*d) for d in dims],
                            MiktConfig(lateral=lateral, mixing=mixing, rl_encoder_grad=teachers != 2))
    with torch.no_grad():  # mixing weights away from their init, so every term counts
        agent.mix_logits_pi.normal_()
    x = torch.empty(1, 181)
    for active in (True, False):
        agent.teacher_active = active
        actor = agent.rollout_actor(x)
        with torch.inference_mode():
            for seed in range(20):
                x.copy_(torch.randn(1, 181, generator=torch.Generator().manual_seed(seed)) * 2)
                assert torch.equal(actor(), agent.action_mean(x))


def test_mean_and_value_equal_evaluate_actions(agent):
    obs = torch.randn(32, 139)
    mean, value, losses = agent.evaluate_actions(obs)
    assert losses  # the full pass also computes the extra terms; mean_and_value skips them
    assert all(torch.equal(a, b) for a, b in zip(agent.mean_and_value(obs), (mean, value), strict=True))


# --- several teachers: the two mixing forms --------------------------------------------------------------

def two_teacher_agent(mixing, lateral="identity", **options):
    torch.manual_seed(0)
    return MiktActorCritic(181, 22, [frozen_teacher(97, 10), frozen_teacher(139, 16)],
                           MiktConfig(mixing=mixing, lateral=lateral, coupling_schedule="constant", **options))


@pytest.mark.parametrize("mixing", ["per-teacher", "shared"])
def test_mixing_weights_are_a_distribution_over_the_forms_sources(mixing):
    agent = two_teacher_agent(mixing)
    sources = 1 + (2 if mixing == "per-teacher" else 1)  # shared: exactly two logits per layer
    for w in agent.mixing_weights():
        assert w.shape == (2, sources)
        assert torch.allclose(w.sum(-1), torch.ones(2))
    assert agent.mixing_weights()[0][0, 0].item() == pytest.approx(initial_student_weight(2, mixing), abs=1e-6)
    assert initial_student_weight(2, "shared") == pytest.approx(0.4725, abs=1e-4)
    assert initial_student_weight(2) == pytest.approx(0.3094, abs=1e-4)


@pytest.mark.parametrize("lateral", ["identity", "projection"])
def test_shared_mixing_is_one_teacher_share_over_the_sum_of_the_teachers(lateral):
    agent = two_teacher_agent("shared", lateral)
    with torch.no_grad():
        agent.mix_logits_pi.copy_(torch.tensor([[0.3, -0.2], [0.1, 0.4]]))
    obs = torch.randn(6, 181)
    embs = agent.embeddings(obs)
    w = torch.softmax(agent.mix_logits_pi, -1)
    x = obs
    for j, (weight, bias) in enumerate(agent.pi.layer_params):
        zs = [t.pi.preactivations(e)[j] for t, e in zip(agent.teachers, embs, strict=True)]
        if lateral == "projection":
            zs = [z @ us[j].weight.T for z, us in zip(zs, agent.lateral_pi, strict=True)]
        x = torch.tanh(w[j, 0] * (x @ weight.T + bias) + w[j, 1] * (zs[0] + zs[1]))
    expected = x @ agent.pi.head.weight.T + agent.pi.head.bias
    assert torch.allclose(agent.action_mean(obs), expected, atol=1e-5)


def test_per_teacher_mixing_weighs_each_teacher_by_its_own_logit():
    agent = two_teacher_agent("per-teacher")
    with torch.no_grad():
        agent.mix_logits_vf.copy_(torch.tensor([[0.3, -0.2, 0.5], [0.1, 0.4, -1.0]]))
    obs = torch.randn(6, 181)
    embs = agent.embeddings(obs)
    w = torch.softmax(agent.mix_logits_vf, -1)
    x = obs
    for j, (weight, bias) in enumerate(agent.vf.layer_params):
        zs = [t.vf.preactivations(e)[j] for t, e in zip(agent.teachers, embs, strict=True)]
        x = torch.tanh(w[j, 0] * (x @ weight.T + bias) + w[j, 1] * zs[0] + w[j, 2] * zs[1])
    expected = (x @ agent.vf.head.weight.T + agent.vf.head.bias).squeeze(-1)
    assert torch.allclose(agent.value(obs), expected, atol=1e-5)


@pytest.mark.parametrize("lateral", ["identity", "projection"])
def test_with_one_teacher_the_two_mixing_forms_are_the_same_model(lateral):
    # one teacher: softmax over [student, teacher] either way, the same parameters drawn in the same order
    agents = []
    for mixing in ("per-teacher", "shared"):
        torch.manual_seed(3)
        agents.append(MiktActorCritic(139, 16, [frozen_teacher(97, 10)], MiktConfig(mixing=mixing, lateral=lateral)))
    per, shared = agents
    assert per.state_dict().keys() == shared.state_dict().keys()
    assert all(torch.equal(v, shared.state_dict()[k]) for k, v in per.state_dict().items())
    obs = torch.randn(8, 139)
    for a, b in zip(per.evaluate_actions(obs)[:2], shared.evaluate_actions(obs)[:2], strict=True):
        assert torch.equal(a, b)
    assert per.diagnostics() == shared.diagnostics()


@pytest.mark.parametrize("mixing", ["per-teacher", "shared"])
def test_teacher_weights_are_logged_per_layer_and_teacher(mixing):
    agent = two_teacher_agent(mixing)
    d = agent.diagnostics()
    names = ["t0", "t1"] if mixing == "per-teacher" else ["shared"]
    for branch in ("pi", "vf"):
        for j in range(2):
            total = d[f"p_{branch}_{j}"] + sum(d[f"w_{branch}_{j}_{n}"] for n in names)
            assert total == pytest.approx(1.0)
    agent.teacher_active = False
    assert all(v == 0.0 for k, v in agent.diagnostics().items() if k.startswith("w_"))


def test_one_teacher_logs_no_teacher_weights_of_its_own(agent):
    assert not [k for k in agent.diagnostics() if k.startswith("w_")]


def test_student_weight_ramp_pushes_only_layers_below_the_schedule():
    torch.manual_seed(0)
    agent = MiktActorCritic(97, 10, [frozen_teacher(97, 10)], MiktConfig(coupling_ramp="student-weight"))
    obs = torch.randn(4, 97)
    agent.set_progress(0.45 + 0.45 * 0.3)  # floor 0.3, below p = 0.4725: nothing to push
    assert agent.evaluate_actions(obs)[2]["loss_coupling"].item() == 0.0
    agent.set_progress(0.45 + 0.45 * 0.8)  # floor 0.8: -log p + log 0.8 on every layer
    expected = (1.0 + 0.1) * (math.log(0.8) - math.log(initial_student_weight()))
    assert agent.evaluate_actions(obs)[2]["loss_coupling"].item() == pytest.approx(expected, rel=1e-5)
    with pytest.raises(ValueError, match="constant schedule has none"):
        MiktConfig(coupling_ramp="student-weight", coupling_schedule="constant")


def test_the_q_log_std_clamp_can_be_turned_off_as_in_the_authors_and_cat_s_code():
    torch.manual_seed(0)
    agent = MiktActorCritic(139, 16, [frozen_teacher(97, 10)], MiktConfig(mi_log_std_clamp=False))
    decoder = agent.decoders[0]
    with torch.no_grad():
        decoder.log_std.fill_(-9.0)
    obs, emb = torch.zeros(4, 139), torch.zeros(4, 97)
    unclamped = decoder.neg_log_prob(obs, emb)
    clamped = MiktActorCritic(139, 16, [frozen_teacher(97, 10)], MiktConfig()).decoders[0]
    clamped.load_state_dict(decoder.state_dict())
    assert not torch.allclose(unclamped, clamped.neg_log_prob(obs, emb))
