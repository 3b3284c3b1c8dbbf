"""The hand-over at the three-phase schedule's drop: drop (the authors'), fold, fold-linear, fold-fit, distil
and fade."""

import json

import pytest
import torch
from pydantic import ValidationError
from torch.nn import functional as F

from helpers import mikt
from miktcli.engine.policies import GaussianActorCritic
from miktcli.engine.ppo import complete_state, state_misfit
from miktcli.errors import MiktError
from miktcli.methods.mikt import MiktActorCritic, MiktConfig


def frozen_teacher(obs_dim, act_dim):
    torch.manual_seed(1)
    t = GaussianActorCritic(obs_dim, act_dim, (64, 64), (64, 64))
    t.requires_grad_(False)
    return t


def trained_like_agent(handover, teachers=1, **options):
    """An agent whose teachers still hold a real share (logits moved from their initial values)."""
    torch.manual_seed(0)
    ts = [frozen_teacher(11, 3), frozen_teacher(17, 6)][:teachers]
    agent = MiktActorCritic(13, 4, ts, MiktConfig(handover=handover, **options))
    with torch.no_grad():
        for logits in (agent.mix_logits_pi, agent.mix_logits_vf):
            logits[:, 0] += torch.tensor([1.5, 1.0])  # p_student ≈ 0.8 and ≈ 0.7
    return agent


def layer0(agent, obs):
    w, b = agent.pi.layer_params[0]
    return F.linear(obs, w, b)


def mixed_layer0(agent, obs):
    w_pi, _ = agent.mixing_weights()
    tz = agent._teacher_z([t.pi for t in agent.teachers], agent.embeddings(obs), agent.lateral_pi)
    return agent._layer_terms(agent.pi, obs, tz, w_pi)[0], w_pi[0, 0] * layer0(agent, obs)


def hand_over(agent, obs):
    """Train-like sequence: a rollout before the drop, then the schedule crosses it."""
    agent.set_progress(0.85)
    with torch.no_grad():
        agent.observe_rollout(obs, 0.9)
    agent.set_progress(0.9)
    assert not agent.teacher_active


@pytest.mark.parametrize("teachers", [1, 2])
def test_fold_keeps_each_pre_activation_up_to_the_teachers_deviation_from_their_mean(teachers):
    agent, obs = trained_like_agent("fold", teachers), torch.randn(512, 13)
    with torch.no_grad():
        (_, c), student_part = mixed_layer0(agent, obs)
    hand_over(agent, obs)
    with torch.no_grad():
        folded = layer0(agent, obs)
    torch.testing.assert_close(folded, student_part + c.mean(0), atol=1e-5, rtol=1e-5)


def mixed_vs_student_gap(handover, obs):
    agent = trained_like_agent(handover)
    with torch.no_grad():
        mixed = agent.action_mean(obs), agent.value(obs)
    hand_over(agent, obs)
    student = agent.student_only()
    with torch.no_grad():
        alone = student.action_mean(obs), student.value(obs)
    return [float((a - b).square().mean()) for a, b in zip(mixed, alone, strict=True)]


def test_each_fold_is_closer_to_the_mixed_network_than_dropping_the_teachers():
    obs = torch.randn(2048, 13)
    drop, fold, linear = (mixed_vs_student_gap(h, obs) for h in ("drop", "fold", "fold-linear"))
    for branch in (0, 1):  # policy mean, value
        assert linear[branch] < fold[branch] < drop[branch]


def held_out_gap(handover, fit_obs, new_obs, **options):
    """Mean squared gap between the mixed network and the student after the hand-over, on states it did not
    see (the same distribution)."""
    agent = trained_like_agent(handover, **options)
    with torch.no_grad():
        agent.pi.head.weight.mul_(100.0)  # a trained policy's means, not the initial ~0.01
        mixed = agent.action_mean(new_obs), agent.value(new_obs)
    hand_over(agent, fit_obs)
    with torch.no_grad():
        alone = agent.action_mean(new_obs), agent.value(new_obs)
    return [float((a - b).square().mean()) for a, b in zip(mixed, alone, strict=True)], agent


def test_fold_fit_is_closer_to_the_mixed_network_than_fold_linear_on_states_it_did_not_see():
    torch.manual_seed(3)
    fit_obs, new_obs = torch.randn(2048, 13), torch.randn(1024, 13)
    linear, _ = held_out_gap("fold-linear", fit_obs, new_obs)
    fitted, agent = held_out_gap("fold-fit", fit_obs, new_obs)
    for branch in (0, 1):  # policy mean, value (0.41 and 0.30 of fold-linear's gap when written)
        assert fitted[branch] < 0.6 * linear[branch]
    record = agent.handover_details()
    assert record["states"] == 2048 and record["steps"] == 400
    for branch in ("pi", "vf"):
        assert record[f"{branch}_heldout_error_fit"] < record[f"{branch}_heldout_error_fold_linear"]


def test_fold_fit_keeps_the_last_states_in_a_ring_and_refuses_to_fit_on_none():
    agent = trained_like_agent("fold-fit", fit_states=100)
    agent.set_progress(0.85)
    first, second = torch.randn(70, 13), torch.randn(70, 13)
    with torch.no_grad():
        agent.observe_rollout(first, 0.87)
        agent.observe_rollout(second, 0.9)
    assert int(agent.fit_count) == 140
    torch.testing.assert_close(agent.fit_obs[:40], second[30:], rtol=0, atol=0)  # wrapped round
    torch.testing.assert_close(agent.fit_obs[40:70], first[40:], rtol=0, atol=0)
    torch.testing.assert_close(agent.fit_obs[70:], second[:30], rtol=0, atol=0)
    empty = trained_like_agent("fold-fit")
    empty.set_progress(0.85)
    with pytest.raises(MiktError, match="no observations to fit on"):
        empty.set_progress(0.9)


def test_fold_fit_resumed_before_the_drop_fits_the_same_and_loads_across_hand_overs():
    obs = torch.randn(512, 13)
    live = trained_like_agent("fold-fit", fit_steps=30)
    live.set_progress(0.85)
    with torch.no_grad():
        live.observe_rollout(obs, 0.9)
    checkpoint = {k: v.clone() for k, v in live.state_dict().items()}
    live.set_progress(0.9)
    resumed = trained_like_agent("fold-fit", fit_steps=30)
    resumed.load_state_dict(checkpoint)
    resumed.restore_progress(0.85)
    resumed.set_progress(0.9)
    for k, v in live.state_dict().items():
        assert torch.equal(resumed.state_dict()[k], v), k
    # a fold-linear run's checkpoint branches into fold-fit (no states kept yet) and back
    linear = trained_like_agent("fold-linear")
    assert state_misfit(linear, checkpoint) is None
    linear.load_state_dict(complete_state(linear, checkpoint))
    fresh = trained_like_agent("fold-fit")
    linear_state = linear.state_dict()
    assert state_misfit(fresh, linear_state) is None
    fresh.load_state_dict(complete_state(fresh, linear_state))
    assert int(fresh.fit_count) == 0


def test_drop_leaves_the_weights_as_they_are():
    agent, obs = trained_like_agent("drop"), torch.randn(64, 13)
    before = {k: v.clone() for k, v in agent.pi.state_dict().items()}
    hand_over(agent, obs)
    assert all(torch.equal(before[k], v) for k, v in agent.pi.state_dict().items())


def test_a_restored_schedule_does_not_fold_again_and_a_resume_before_the_drop_folds_the_same():
    obs = torch.randn(256, 13)
    live = trained_like_agent("fold-linear")
    live.set_progress(0.85)
    with torch.no_grad():
        live.observe_rollout(obs, 0.9)
    checkpoint = {k: v.clone() for k, v in live.state_dict().items()}  # holds the fold statistics
    live.set_progress(0.9)

    resumed = trained_like_agent("fold-linear")
    resumed.load_state_dict(checkpoint)
    resumed.restore_progress(0.85)  # as PPOTrainer.load_state does
    resumed.set_progress(0.9)
    for k, v in live.state_dict().items():
        torch.testing.assert_close(resumed.state_dict()[k], v, rtol=0, atol=0)

    after = {k: v.clone() for k, v in live.state_dict().items()}
    again = trained_like_agent("fold-linear")
    again.load_state_dict(after)
    again.restore_progress(0.9)  # resumed after the drop: the weights are folded already
    again.set_progress(0.95)
    for k, v in after.items():
        assert torch.equal(again.state_dict()[k], v), k


def test_distil_trains_only_the_teacher_free_path_and_only_in_its_window():
    agent, obs = trained_like_agent("distil", handover_window=0.1), torch.randn(64, 13)
    agent.set_progress(0.7)
    assert "loss_distil" not in agent.evaluate_actions(obs)[2]
    agent.set_progress(0.85)
    assert agent.phase(0.85) == "handover-window"
    loss = agent.evaluate_actions(obs)[2]["loss_distil"]
    assert loss > 0
    agent.zero_grad(set_to_none=True)
    loss.backward()
    def reached(ps):
        return any(p.grad is not None and p.grad.abs().sum() > 0 for p in ps)
    assert reached(agent.pi.parameters()) and reached(agent.vf.parameters())
    assert not reached(agent.encoders.parameters())
    assert not reached([agent.mix_logits_pi, agent.mix_logits_vf, agent.log_std])


def test_the_options_name_what_they_need():
    with pytest.raises(ValidationError, match="constant schedule never drops"):
        MiktConfig(handover="fold", coupling_schedule="constant")
    with pytest.raises(ValidationError, match="longer than the training before the drop"):
        MiktConfig(handover="distil", handover_window=0.95)
    assert MiktConfig().handover == "drop"  # the authors' behaviour stays the default
    assert [MiktConfig().phase(f) for f in (0.1, 0.5, 0.9)] == ["independent", "ramp", "teacher-free"]


# --- a whole run ---------------------------------------------------------------------------------------------

# five iterations: fractions 0, 0.2, 0.4, 0.6, 0.8; the ramp from iteration 2, the drop at iteration 3
SHORT_SCHEDULE = ("--steps", 10240, "--ramp-start", 0.2, "--drop-teacher-at", 0.5, "--eval-episodes", 2)


@pytest.mark.slow
@pytest.mark.parametrize("handover", ["drop", "fold", "fold-fit"])
def test_a_run_records_both_sides_of_the_hand_over_and_keeps_the_checkpoint_before_it(registry, handover, teacher):
    result = json.loads(mikt("transfer", "--from", "tiny", "--to", "hopper", *SHORT_SCHEDULE,
                             "--handover", handover, "--json").stdout)
    record = result["handover"]
    assert record["at_step"] == 6144
    assert record["with_teachers"]["episodes"] == record["without_teachers"]["episodes"] == 2
    if handover == "fold-fit":  # fitted on the rollout before the drop, and no worse than fold-linear on held-out
        assert record["fit"]["states"] == 2048
        assert record["fit"]["pi_heldout_error_fit"] <= record["fit"]["pi_heldout_error_fold_linear"]
    else:
        assert "fit" not in record
    run = registry / "runs" / result["run"]
    assert json.loads((run / "run.json").read_text())["result"]["handover"] == record
    kept = sorted(p.name for p in run.glob("checkpoint-*.safetensors"))
    assert kept == ["checkpoint-before-ramp.safetensors", "checkpoint-before-teacher-free.safetensors"]


@pytest.mark.slow
def test_eval_handover_measures_the_drop_again_as_training_did_and_with_more_episodes(registry, teacher):
    source = json.loads(mikt("transfer", "--from", "tiny", "--to", "hopper", *SHORT_SCHEDULE, "--handover", "fold",
                             "--json").stdout)
    again = json.loads(mikt("eval", source["run"], "--handover", "--episodes", 2, "--json").stdout)
    recorded = source["handover"]
    assert again["at_step"] == recorded["at_step"] == 6144 and again["handover"] == "fold"
    # the same checkpoint, hand-over, seeds and episodes: the card's numbers
    for side in ("with_teachers", "without_teachers", "kept_fraction"):
        assert again[side] == recorded[side], side
    assert again["recorded"] == recorded
    more = json.loads(mikt("eval", source["run"], "--handover", "--episodes", 5, "--json").stdout)
    assert more["with_teachers"]["episodes"] == more["without_teachers"]["episodes"] == 5
    line = mikt("eval", source["run"], "--handover", "--episodes", 2).stdout
    assert "with the teachers" in line and "kept" in line and "recorded in training: 2 episodes" in line
    assert "cannot be combined with --handover" in mikt("eval", source["run"], "--handover", "--with-teacher",
                                                        code=2).output
    ppo = json.loads(mikt("transfer", "--to", "hopper", "--method", "vpg", "--steps", 2048, "--eval-episodes", 1,
                          "--json").stdout)["run"]
    assert "has no teachers" in mikt("eval", ppo, "--handover", code=1).output


@pytest.mark.slow
def test_a_branch_starts_from_the_kept_checkpoint_and_hands_over_its_own_way(registry, teacher):
    source = json.loads(mikt("transfer", "--from", "tiny", "--to", "hopper", *SHORT_SCHEDULE, "--json").stdout)
    branch = json.loads(mikt("transfer", "--branch", source["run"], "--at", "before-teacher-free",
                             "--handover", "fold", "--json").stdout)
    card = json.loads((registry / "runs" / branch["run"] / "run.json").read_text())
    assert card["branched_from"] == {"run": source["run"], "checkpoint": "before-teacher-free", "step": 6144}
    assert card["config"]["options"]["handover"] == "fold"
    assert card["config"]["options"]["ramp_start"] == 0.2  # the rest is the source's
    assert card["config"]["eval_episodes"] == 2
    # the same weights before the hand-over: the mixed policy scores the same on the same episodes
    assert branch["handover"]["with_teachers"] == source["handover"]["with_teachers"]
    rows = [json.loads(line) for line in (registry / "runs" / branch["run"] / "metrics.jsonl").read_text().splitlines()]
    source_rows = [json.loads(line) for line in
                   (registry / "runs" / source["run"] / "metrics.jsonl").read_text().splitlines()]
    assert [r["steps"] for r in rows] == [2048, 4096, 6144, 8192, 10240]
    assert rows[:3] == source_rows[:3]


@pytest.mark.slow
def test_a_branch_refuses_what_it_cannot_do_before_a_run_exists(registry, teacher):
    source = json.loads(mikt("transfer", "--from", "tiny", "--to", "hopper", *SHORT_SCHEDULE, "--json").stdout)["run"]
    runs_before = sorted(p.name for p in (registry / "runs").iterdir())
    out = mikt("transfer", "--branch", source, "--at", "before-nothing", code=1).output
    assert "kept no checkpoint 'before-nothing'" in out and "before-teacher-free" in out
    out = mikt("transfer", "--branch", source, "--at", "before-teacher-free", "--lateral", "projection", code=1).output
    assert "do not fit" in out
    assert "go together" in mikt("transfer", "--branch", source, code=2).output
    assert "cannot be combined with --branch" in mikt("transfer", "--branch", source, "--at",
                                                            "before-teacher-free", "--steps", 4096, code=2).output
    assert sorted(p.name for p in (registry / "runs").iterdir()) == runs_before


def test_a_study_report_shows_each_run_s_hand_over_and_slowdown():
    from types import SimpleNamespace

    from miktcli.studies.handover import HandoverFigures
    from miktcli.studies.render_markdown import handover_lines, slowdown_lines

    f = HandoverFigures(run="run7", handover="fold", at_step=1_800_384, with_teachers=5168.0,
                        without_teachers=5000.0, kept=5000 / 5168, before=4000.0, after=4100.0,
                        after_200k=4200.0, final=4300.0)
    summary = SimpleNamespace(handovers=[("a+b>c|mikt|0", f)], handover_pairs=[],
                              slowdowns=[("a+b>c|mikt|1", "run8", {"phase": "ramp", "step": 462848, "factor": 2.7})])
    text = "\n".join(handover_lines(summary) + slowdown_lines(summary))
    assert "| a+b>c | mikt | 0 | run7 | fold | 1,800,384 | 5,168 | 5,000 | 97% | 4,000 | 4,100 | +100 |" in text
    assert "| a+b>c | mikt | 1 | run8 | ramp | 462,848 | 2.7× |" in text
    assert handover_lines(SimpleNamespace(handovers=[])) == []


def test_a_pair_s_hand_overs_are_seed_means_beside_the_baseline_over_the_same_windows():
    from types import SimpleNamespace

    from miktcli.studies.handover import HandoverFigures, pair_handover, pair_handover_json
    from miktcli.studies.render_markdown import handover_pair_lines

    def figures(run, with_teachers, without, before, after):
        return HandoverFigures(run=run, handover="fold-linear", at_step=100_000, with_teachers=with_teachers,
                               without_teachers=without, kept=without / with_teachers, before=before, after=after,
                               after_200k=after, final=None)

    seeds = [figures("run1", 4000.0, 2000.0, 3000.0, 2800.0), figures("run2", 2000.0, 2600.0, 1000.0, 1000.0)]
    # the baseline's per-update returns: 10 before the drop's window, 50k-100k at 1, 100k-150k at 5, later 99
    rows = [[{"steps": s, "episode_return_iter": 10.0 if s <= 50_000 else 1.0 if s <= 100_000 else
              5.0 if s <= 150_000 else 99.0} for s in range(10_000, 200_001, 10_000)]]
    h = pair_handover("a+b → c", "mikt", seeds, "vpg", rows + [[{"steps": 60_000, "episode_return_iter": 3.0}]])
    assert (h.with_teachers, h.without_teachers, h.before, h.after) == (3000.0, 2300.0, 2000.0, 1900.0)
    assert h.kept == pytest.approx(2300 / 3000)  # the ratio of seed means, not the mean of the ratios (0.825)
    assert (h.baseline_runs, h.baseline_before, h.baseline_after) == (2, 2.0, 5.0)  # the second has no "after"
    assert h.change == -100.0 and h.baseline_change == 3.0
    lines = handover_pair_lines(SimpleNamespace(handover_pairs=[h], grid=SimpleNamespace(baseline="vpg")))
    assert "| a+b → c | mikt | 2 | 3,000 | 2,300 | 77% | 2,000 | 1,900 | -100 | 2 | 2 | 5 | +3 |" in lines
    assert pair_handover_json(h)["kept"] == pytest.approx(2300 / 3000)
    alone = pair_handover("a → c", "mikt", seeds[:1], "vpg", [])
    assert alone.baseline_runs == 0 and pair_handover_json(alone)["baseline_change"] is None
    assert "| 0 | — | — | — |" in handover_pair_lines(SimpleNamespace(handover_pairs=[alone],
                                                                         grid=SimpleNamespace(baseline="vpg")))[-2]
    # a baseline with teachers drops them too: no control columns
    mixed = pair_handover("a → c", "mikt", seeds, "", [])
    summary = SimpleNamespace(handover_pairs=[mixed], grid=SimpleNamespace(baseline="pick"))
    text = "\n".join(handover_pair_lines(summary))
    assert "pick" not in text and "| a → c | mikt | 2 | 3,000 | 2,300 | 77% | 2,000 | 1,900 | -100 |\n" in text


@pytest.mark.parametrize("teachers", [1, 2])
def test_fade_moves_the_mixed_network_to_the_teacher_free_student_across_the_window(teachers):
    agent, obs = trained_like_agent("fade", teachers, handover_window=0.1), torch.randn(64, 13)
    student = agent.student_only()
    with torch.no_grad():
        agent.set_progress(0.79)  # before the window: the learned weights
        assert not agent.fading
        before = agent.action_mean(obs)
        agent.set_progress(0.85)  # half-way: u = 0.5
        w_pi, _ = agent.forward_weights()
        p = agent.mixing_weights()[0]
        torch.testing.assert_close(w_pi[:, 0], p[:, 0] + 0.5 * (1 - p[:, 0]))
        torch.testing.assert_close(w_pi.sum(1), torch.ones(2))
        assert torch.equal(agent.rollout_actor(obs)(), agent.action_mean(obs))  # the fast path fades too
        agent.set_progress(0.9 - 1e-9)  # the window's end: (almost) the student alone
        torch.testing.assert_close(agent.action_mean(obs), student.action_mean(obs), atol=1e-5, rtol=0)
        torch.testing.assert_close(agent.value(obs), student.value(obs), atol=1e-5, rtol=0)
    assert not torch.allclose(before, student.action_mean(obs), atol=1e-3)
