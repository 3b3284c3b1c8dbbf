"""Seeds together: a cell's seeds trained in one process, their update batched (miktcli.engine.together)."""

import copy
import json

import numpy as np
import pytest
import torch

from helpers import ctrl_c_at_second_call, mikt, runs
from miktcli.engine.policies import GaussianActorCritic
from miktcli.engine.ppo import PPOConfig, PPOTrainer
from miktcli.engine.together import SeedsTogether
from miktcli.envs import make_env
from miktcli.methods.mikt import MiktActorCritic, MiktConfig

CONFIG = PPOConfig(n_steps=64, minibatch_size=16, epochs=2, kl_coef=0.1)


def agent_for(kind: str, seed: int):
    torch.manual_seed(seed)
    if kind == "ppo":
        return GaussianActorCritic(11, 3)
    torch.manual_seed(100)  # the same teachers in every seed, as a cell has
    teachers = [GaussianActorCritic(13, 4).requires_grad_(False), GaussianActorCritic(7, 2).requires_grad_(False)]
    torch.manual_seed(seed)
    return MiktActorCritic(11, 3, teachers, MiktConfig(coupling_schedule="constant"))


def trainers(agents, config=CONFIG):
    out = [PPOTrainer(copy.deepcopy(a), lambda: make_env("hopper"), config, 64 * 4, seed) for seed, a in
           enumerate(agents)]
    for t in out:
        t.begin_iteration()
    return out


@pytest.mark.parametrize("kind", ["ppo", "mikt"])
def test_each_seed_s_update_is_its_update_alone_to_float_rounding(kind):
    agents = [agent_for(kind, seed) for seed in range(3)]
    alone, together = trainers(agents), trainers(agents)
    batches = [t._values_and_targets(t.collect()[0]) for t in alone]
    metrics_alone = [t.update(b) for t, b in zip(alone, batches, strict=True)]
    metrics_together = SeedsTogether(together).update(batches)
    for a, b, ma, mb in zip(alone, together, metrics_alone, metrics_together, strict=True):
        assert ma.keys() == mb.keys()
        for key in ma:
            assert mb[key] == pytest.approx(ma[key], rel=1e-4, abs=1e-6), key
        for (name, pa), pb in zip(a.agent.named_parameters(), b.agent.parameters(), strict=True):
            assert torch.allclose(pa, pb, atol=1e-5), name
        for key in ("exp_avg", "exp_avg_sq"):
            sa, sb = a.optimizer.state[a.flat.flat][key], b.optimizer.state[b.flat.flat][key]
            assert torch.allclose(sa, sb, rtol=1e-3, atol=1e-9), key
    # the seeds really differ, so matching them one by one means something
    assert not torch.allclose(together[0].flat.flat, together[1].flat.flat)


@pytest.mark.parametrize("kind", ["ppo", "mikt"])
def test_the_lock_step_rollout_is_each_seed_s_rollout_alone_to_float_rounding(kind):
    """One batched forward a step for every seed (the teachers once over all their rows), then each seed's
    own noise, normaliser and envs: the actions a seed takes alone, up to the batched matmul's rounding."""
    agents = [agent_for(kind, seed) for seed in range(3)]
    alone, together = trainers(agents), trainers(agents)
    collected = SeedsTogether(together).collect()
    for trainer, (rollout, stats, wall) in zip(alone, collected, strict=True):
        own, own_stats = trainer.collect()
        assert np.allclose(rollout.actions, own.actions, atol=1e-6)
        assert np.allclose(rollout.obs, own.obs, atol=1e-5)
        assert stats["episodes_finished"] == own_stats["episodes_finished"] > 0  # episodes end inside it
        assert wall > 0 and stats["time_inference"] > 0
    assert not np.allclose(collected[0][0].actions, collected[1][0].actions)  # the seeds differ


@pytest.mark.slow
def test_the_compiled_stacked_update_is_each_seed_s_update_alone_to_float_rounding():
    agents = [agent_for("mikt", seed) for seed in range(2)]
    alone, together = trainers(agents), trainers(agents, CONFIG.model_copy(update={"compile_loss": True}))
    batches = [t._values_and_targets(t.collect()[0]) for t in alone]
    metrics_alone = [t.update(b) for t, b in zip(alone, batches, strict=True)]
    metrics_together = SeedsTogether(together).update(batches)
    for a, b, ma, mb in zip(alone, together, metrics_alone, metrics_together, strict=True):
        for key in ma:
            assert mb[key] == pytest.approx(ma[key], rel=1e-4, abs=1e-6), key
        assert torch.allclose(a.flat.flat.detach(), b.flat.flat.detach(), atol=1e-5)


def test_seeds_train_together_only_where_they_are_one_problem():
    agents = [agent_for("ppo", seed) for seed in range(2)]
    with pytest.raises(ValueError, match="at least two"):
        SeedsTogether(trainers(agents[:1]))
    mixed = trainers(agents[:1]) + trainers(agents[1:], CONFIG.model_copy(update={"clip_range": 0.1}))
    with pytest.raises(ValueError, match="same PPO settings"):
        SeedsTogether(mixed)
    other = trainers(agents)
    other[1].iteration = 1
    with pytest.raises(ValueError, match="one iteration"):
        SeedsTogether(other)


SMALL = ["--to", "hopper", "--method", "vpg", "--steps", 256, "--ppo", "n_steps=64", "--eval-episodes", 1]


def test_transfer_seeds_trains_one_run_per_seed_and_cards_name_the_group(registry):
    out = mikt("transfer", *SMALL, "--seeds", "3-4", "--json")
    results = json.loads(out.stdout)
    ids = [r["run"] for r in results]
    listed = {r["run_id"]: r for r in runs(registry)}
    assert len(ids) == 2 and set(ids) <= listed.keys()
    for run_id, seed in zip(ids, (3, 4), strict=True):
        card = json.loads((registry / "runs" / run_id / "run.json").read_text())
        assert card["status"] == "completed" and card["seed"] == seed
        assert card["seeds_together"] == ids
        assert (registry / "runs" / run_id / "student.safetensors").exists()
        rows = [json.loads(line) for line in (registry / "runs" / run_id / "metrics.jsonl").read_text().splitlines()]
        assert [r["iteration"] for r in rows] == [1, 2, 3, 4]
    first, second = (json.loads((registry / "runs" / i / "metrics.jsonl").read_text().splitlines()[0]) for i in ids)
    assert first["loss_policy"] != second["loss_policy"]  # two seeds, not one run written twice


@pytest.mark.parametrize("seeds, message", [("0-0", "2 to"), ("a-b", "like 0-4"), ("1,1", "twice")])
def test_bad_seed_lists_are_one_line_errors(registry, seeds, message):
    out = mikt("transfer", *SMALL, "--seeds", seeds, code=1)
    assert message in out.output
    assert not (registry / "runs").exists() or not list((registry / "runs").iterdir())


def test_seeds_and_seed_together_are_refused(registry):
    out = mikt("transfer", *SMALL, "--seeds", "0-1", "--seed", 3, code=2)
    assert "--seeds" in out.output


def test_an_interrupted_group_resumes_together_from_any_of_its_runs(registry, monkeypatch):
    ctrl_c_at_second_call(monkeypatch, SeedsTogether, "update")
    out = mikt("transfer", *SMALL, "--seeds", "0-1", code=1)
    assert "--resume" in out.output
    cards = {r["run_id"]: r for r in runs(registry)}
    assert {c["status"] for c in cards.values()} == {"interrupted"}
    assert {c["steps_done"] for c in cards.values()} == {64}
    second = sorted(cards)[1]
    mikt("transfer", "--resume", second)
    for run_id in cards:
        card = json.loads((registry / "runs" / run_id / "run.json").read_text())
        assert card["status"] == "completed" and card["steps_done"] == 256


def test_a_seed_left_behind_catches_up_alone_then_trains_with_the_others(registry, monkeypatch):
    from miktcli.registry.runs import open_run
    from miktcli.workflows.session import Job, run_to_end
    from miktcli.workflows.together import train_transfers_together

    let_it_train = ctrl_c_at_second_call(monkeypatch, SeedsTogether, "update")
    mikt("transfer", *SMALL, "--seeds", "0-1", code=1)
    let_it_train()
    first, second = sorted(r["run_id"] for r in runs(registry))
    with Job(open_run(registry, second), registry) as job:  # as if stopped between the two checkpoints
        for metrics in job.trainer.run():
            list(job.record(metrics))
            break
    group = [open_run(registry, first), open_run(registry, second)]
    assert [r.card.steps_done for r in group] == [64, 128]
    results = run_to_end(train_transfers_together(group, registry, 1))
    assert len(results) == 2
    for run_id in (first, second):
        rows = (registry / "runs" / run_id / "metrics.jsonl").read_text().splitlines()
        assert [json.loads(r)["iteration"] for r in rows] == [1, 2, 3, 4]


@pytest.mark.slow
def test_a_study_with_seeds_together_trains_each_cell_s_seeds_in_one_group(registry, tmp_path, teacher):
    from pathlib import Path

    grid = (Path(__file__).resolve().parents[1] / "benchmarks" / "grids" / "tiny.toml").read_text()
    assert "seeds = [0, 1]" in grid
    path = tmp_path / "grid.toml"
    path.write_text("seeds_together = true\n" + grid)
    out = tmp_path / "results"
    done = mikt("study", path, "--out", out)
    state = json.loads((out / "state.json").read_text())
    assert len(state) == 4 and "4/4" in done.output
    groups = set()
    for run_id in state.values():
        card = json.loads((registry / "runs" / run_id / "run.json").read_text())
        assert card["status"] == "completed" and len(card["seeds_together"]) == 2
        groups.add(tuple(card["seeds_together"]))
    assert len(groups) == 2  # one per (pair, method), each of its two seeds
    mikt("study", path, "--out", tmp_path / "other", "--workers", 1)  # on Ray: a cell's seeds in one task
    cards = [json.loads((registry / "runs" / r / "run.json").read_text())
             for r in json.loads((tmp_path / "other" / "state.json").read_text()).values()]
    assert len(cards) == 4 and all(c["status"] == "completed" and len(c["seeds_together"]) == 2 for c in cards)
