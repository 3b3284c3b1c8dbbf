"""Throughput, side by side in one run: the physics limit, this engine's PPO and MIKT, Stable-Baselines3.

    python benchmarks/throughput.py                 # the full run (~6-8 min on a quiet machine)
    python benchmarks/throughput.py --quick --out /tmp/tp   # a smoke run of every part (tests use it)

One run measures, each as the best (min time) of --repeats, the systems compared alternated:
1. the physics-only limit: Ant's `mj_step` × frame_skip, nothing else;
2. in process (Ant, the paper's settings, 1 env, 1 thread, after one untimed warm-up iteration): this engine's
   PPO (its rollout as a fraction of the physics limit; env / inference / update per env step) against
   Stable-Baselines3's PPO with VecNormalize (benchmarks/sb3_ppo_script.py);
3. whole processes as users run them: `mikt teacher train ant` against the SB3 script (30,720 steps), a
   one-teacher transfer (centipede-six → centipede-eight) and a two-teacher transfer (centipede-four +
   centipede-six → centipede-eight) against PPO from scratch on centipede-eight (`--method vpg`), 20,480 steps;
4. the per-piece breakdown (microbenchmarks, min of repeats): env step through gymnasium and lean,
   observation normaliser, reward scaler and batch-of-one forward (module path and rollout path), and the
   minibatch update step eager and compiled for PPO and MIKT with 1 and 2 teachers.
It writes the figures (JSON) and a Markdown page of tables stamped with the date and the command
(benchmarks/results/throughput.json and throughput.md by default). Needs `pip install -e .[bench]` (SB3).
Absolute figures drift with the machine's load; only the ratios of one run count.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np
import torch

from miktcli.engine.compile_choice import AUTO_MIN_STEPS
from miktcli.engine.policies import GaussianActorCritic
from miktcli.engine.ppo import PPOConfig, PPOTrainer, RewardScaler, flushing_denormals
from miktcli.engine.together import SeedsTogether
from miktcli.envs import make_env
from miktcli.envs.vector import SyncEnvs
from miktcli.methods.mikt import MiktActorCritic, MiktConfig

ROOT = Path(__file__).resolve().parents[1]
# in process at study settings (centipede-eight, compiled update): PPO from scratch, one and two teachers
STUDY_RUNS = {"ppo": None, "mikt_1": ["centipede-six"], "mikt_2": ["centipede-four", "centipede-six"]}
TARGETS = {"rollout_vs_physics": 0.70, "ppo_vs_sb3": 2.5, "teacher_vs_sb3_script": 2.5,
           "one_teacher_vs_ppo": 1.25, "two_teachers_vs_ppo": 1.5, "seeds_together_vs_separate": 1.6}


def best_time(fn: Callable[[], object], number: int, repeats: int) -> float:
    """Seconds per call: the best of `repeats` timings of `number` calls."""
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - t) / number)
    return best


def teacher_net(env: str) -> GaussianActorCritic:
    env_obj = make_env(env)
    obs, act = env_obj.observation_space.shape[0], env_obj.action_space.shape[0]
    env_obj.close()
    return GaussianActorCritic(obs, act).requires_grad_(False)


def mikt_agent(target: str, teachers: list[str]) -> MiktActorCritic:
    probe = make_env(target)
    obs, act = probe.observation_space.shape[0], probe.action_space.shape[0]
    probe.close()
    return MiktActorCritic(obs, act, [teacher_net(t) for t in teachers], MiktConfig(coupling_schedule="constant"))


# --- 1. physics -------------------------------------------------------------------------------------------
def physics_us(env_name: str, number: int, repeats: int) -> float:
    env = make_env(env_name)
    env.reset(seed=0)
    model, data = env.unwrapped.model, env.unwrapped.data
    frame_skip = getattr(env.unwrapped, "frame_skip", 5)
    data.ctrl[:] = 0.1
    return 1e6 * best_time(lambda: mujoco.mj_step(model, data, nstep=frame_skip), number, repeats)


def physics_replay_us(steps: int, seed: int) -> float:
    """Physics alone on the very steps `engine_run(steps, seed)` times: the same run again (the engine is
    deterministic, so it visits the same states), its rollouts' actions then replayed through `mj_step` × 5
    from the same reset, episodes reset where the rollout's ended; only the `mj_step` calls of the timed
    rollouts (not the warm-up's) are timed. The constant-control figure above times a standing Ant, whose
    contacts cost other than those of the gait the rollout actually runs."""
    torch.manual_seed(seed)
    config = PPOConfig()
    trainer = PPOTrainer(GaussianActorCritic(111, 8), lambda: make_env("ant"), config, steps + config.batch_size,
                         seed)
    rollouts = []
    collect = trainer.collect

    def recording_collect():
        ro, stats = collect()
        rollouts.append((ro.actions[:, 0].copy(), ro.dones[:, 0].copy()))
        return ro, stats

    trainer.collect = recording_collect
    for _ in trainer.run():
        pass
    final_qpos = trainer.envs.envs[0].unwrapped.data.qpos.copy()
    trainer.close()
    env = make_env("ant")
    env.reset(seed=seed)
    model, data = env.unwrapped.model, env.unwrapped.data
    frame_skip = env.unwrapped.frame_skip
    clock, total, timed = time.perf_counter, 0.0, 0
    for i, (actions, dones) in enumerate(rollouts):
        for action, done in zip(actions, dones, strict=True):
            data.ctrl[:] = action
            t = clock()
            mujoco.mj_step(model, data, nstep=frame_skip)
            if i:
                total += clock() - t
                timed += 1
            if done:
                env.reset()
    replayed = env.unwrapped.data.qpos.copy()
    env.close()
    if not np.array_equal(replayed, final_qpos):  # not the same steps: the figure would mean nothing
        raise RuntimeError("the physics replay did not end in the rollout's state")
    return 1e6 * total / timed


# --- 2. in process ----------------------------------------------------------------------------------------
def engine_run(steps: int, seed: int, compile_loss: bool = False, env: str = "ant",
               teachers: list[str] | None = None, gradients: str = "autograd") -> dict:
    """This engine's PPO on Ant: autograd's eager update, or its compiled one (compiled in the warm-up), or the
    gradient by hand (gradients="by-hand": what `mikt teacher train` and PPO from scratch run by default). With
    `teachers`, MIKT on `env` with the teacher active and coupled throughout (the first 90 % of a run)."""
    torch.manual_seed(seed)
    config = PPOConfig(compile_loss=compile_loss, kl_coef=0.05 if teachers else 0.0, gradients=gradients)
    if teachers:
        agent = mikt_agent(env, teachers)
    else:
        probe = make_env(env)
        agent = GaussianActorCritic(probe.observation_space.shape[0], probe.action_space.shape[0])
        probe.close()
    trainer = PPOTrainer(agent, lambda: make_env(env), config, steps + config.batch_size, seed)
    iterations = trainer.run()
    next(iterations)  # untimed warm-up
    totals = dict.fromkeys(("time_env", "time_inference", "time_rollout", "time_update"), 0.0)
    t = time.perf_counter()
    for m in iterations:
        for k in totals:
            totals[k] += m[k]
    wall = time.perf_counter() - t
    trainer.close()
    n = trainer.global_step - config.batch_size
    us = {k[5:]: 1e6 * v / n for k, v in totals.items()}
    us["rollout_other"] = us["rollout"] - us["env"] - us["inference"]  # buffers, reward scaling, loop
    return {"steps": n, "wall_s": wall, "steps_per_sec": n / wall, "rollout_steps_per_sec": n / totals["time_rollout"],
            "us_per_step": us, "lean_env": trainer.envs.lean}


def sb3_run(steps: int, seed: int) -> dict:
    from sb3_ppo_script import make_model

    model = make_model(seed)
    model.learn(total_timesteps=2048)  # the same untimed warm-up iteration as the engine's
    t = time.perf_counter()
    model.learn(total_timesteps=steps, reset_num_timesteps=False)
    wall = time.perf_counter() - t
    return {"steps": steps, "wall_s": wall, "steps_per_sec": steps / wall}


# --- 3. whole processes -----------------------------------------------------------------------------------
def whole_process(commands: dict[str, list[str]], repeats: int, env: dict[str, str]) -> dict[str, dict]:
    """Wall time of each command as a fresh process (imports included), best of `repeats`, alternated."""
    times: dict[str, list[float]] = {name: [] for name in commands}
    for _ in range(repeats):
        for name, cmd in commands.items():
            t = time.perf_counter()
            done = subprocess.run(cmd, env=env, capture_output=True, text=True)
            elapsed = time.perf_counter() - t
            if done.returncode:
                raise RuntimeError(f"{shlex.join(cmd)} failed ({done.returncode}): {done.stderr.strip()[-600:]}")
            times[name].append(elapsed)
    return {name: {"command": shlex.join(commands[name]), "wall_s": min(t), "all_s": t} for name, t in times.items()}


def process_commands(steps_teacher: int, steps_transfer: int) -> dict[str, list[str]]:
    py = sys.executable
    transfer = [py, "-m", "miktcli", "transfer", "--to", "centipede-eight", "--steps", str(steps_transfer),
                "--eval-episodes", "1"]
    return {
        "mikt_teacher_train_ant": [py, "-m", "miktcli", "teacher", "train", "ant", "--steps", str(steps_teacher),
                                   "--name", "bench-ant"],
        "sb3_ppo_script": [py, str(ROOT / "benchmarks" / "sb3_ppo_script.py"), "--steps", str(steps_teacher)],
        "ppo_from_scratch_eight": [*transfer, "--method", "vpg"],
        "ppo_from_scratch_eight_autograd": [*transfer, "--method", "vpg", "--ppo", "gradients=autograd"],
        "one_teacher_six_to_eight": [*transfer, "--from", "centipede-six"],
        "two_teachers_four_six_to_eight": [*transfer, "--from", "centipede-four", "--from", "centipede-six"],
    }


def seeds_together(steps: int, seeds: int, repeats: int, env: dict[str, str]) -> dict:
    """A study cell whole process: `seeds` seeds of a two-teacher transfer (four + six → eight, the grid's 10
    evaluation episodes) in one process (`--seeds`), against one process per seed run one after another.
    Best of `repeats` for each side, the sides alternated."""
    py = sys.executable
    cell = [py, "-m", "miktcli", "transfer", "--from", "centipede-four", "--from", "centipede-six", "--to",
            "centipede-eight", "--steps", str(steps)]
    together, separate = [], []
    for _ in range(repeats):
        together.append(whole_process({"cell": [*cell, "--seeds", f"0-{seeds - 1}"]}, 1, env)["cell"]["wall_s"])
        each = whole_process({f"seed {s}": [*cell, "--seed", str(s)] for s in range(seeds)}, 1, env)
        separate.append(sum(r["wall_s"] for r in each.values()))
    return {"seeds": seeds, "steps_per_seed": steps,
            "command_together": shlex.join([*cell[1:], "--seeds", f"0-{seeds - 1}"]),
            "command_separate": shlex.join([*cell[1:], "--seed", "S"]),
            "together_s": min(together), "separate_s": min(separate), "all_together_s": together,
            "all_separate_s": separate}


def together_update(seeds: int, repeats: int, n_steps: int = 1024) -> dict:
    """The update alone, in process: `seeds` two-teacher centipede-eight agents (four + six, the study's KL), one
    epoch over one rollout each, trained one after another (PPOTrainer.update) against together
    (SeedsTogether.update), on the same batches, alternated; best of `repeats`, per seed and minibatch."""
    def make(seed: int) -> PPOTrainer:
        torch.manual_seed(seed)
        agent = mikt_agent("centipede-eight", ["centipede-four", "centipede-six"])
        return PPOTrainer(agent, lambda: make_env("centipede-eight"), PPOConfig(n_steps=n_steps, epochs=1,
                                                                                kl_coef=0.1), 10**6, seed)
    alone = [make(s) for s in range(seeds)]
    together = SeedsTogether([make(s) for s in range(seeds)])
    batches = [t._values_and_targets(t.collect()[0]) for t in alone]
    per = seeds * (n_steps // 64)
    best = {"separate": float("inf"), "together": float("inf")}
    with flushing_denormals(True):
        for _ in range(repeats + 1):  # the first round warms up and is kept only if it is the best
            start = time.perf_counter()
            for trainer, batch in zip(alone, batches, strict=True):
                trainer.update(batch)
            best["separate"] = min(best["separate"], (time.perf_counter() - start) / per)
            start = time.perf_counter()
            together.update(batches)
            best["together"] = min(best["together"], (time.perf_counter() - start) / per)
    for trainer in [*alone, *together.trainers]:
        trainer.close()
    return {"seeds": seeds, "separate_ms_per_seed_minibatch": 1e3 * best["separate"],
            "together_ms_per_seed_minibatch": 1e3 * best["together"]}


def seeds_together_markdown(res: dict) -> list[str]:
    st = res["seeds_together"]
    rows = []
    if "update" in st:
        up = st["update"]
        rows.append(f"| the update alone, in process: {up['seeds']} two-teacher centipede-eight agents, one epoch, "
                    f"together (stacked) vs one after another, per seed and minibatch | "
                    f"{up['together_ms_per_seed_minibatch']:.2f} ms | {up['separate_ms_per_seed_minibatch']:.2f} ms "
                    f"| {up['separate_ms_per_seed_minibatch'] / up['together_ms_per_seed_minibatch']:.2f}× faster "
                    f"| |")
    return rows + [
        f"| a study cell, whole process: {st['seeds']} seeds × {fmt(st['steps_per_seed'])} steps of a two-teacher "
        f"transfer (four + six → eight) in one process (`--seeds`) vs {st['seeds']} processes one after another "
        f"| {st['together_s']:.1f} s | {st['separate_s']:.1f} s | "
        f"{res['ratios']['seeds_together_vs_separate']:.2f}× faster | ≥ {TARGETS['seeds_together_vs_separate']}× |"]


# --- 4. pieces --------------------------------------------------------------------------------------------
def env_pieces(number: int, repeats: int) -> dict:
    out = {}
    for name in ("ant", "centipede-eight", "hopper"):
        row = {}
        for label, lean in (("gymnasium", False), ("lean", True)):
            envs = SyncEnvs([make_env(name)], seed=0, lean=lean)
            action = np.zeros((1, envs.action_low.shape[0]), np.float32)
            row[f"step_{label}_us"] = 1e6 * best_time(lambda e=envs, a=action: e.step(a), number, repeats)
            envs.close()
        row["physics_us"] = physics_us(name, number, repeats)
        out[name] = row
    return out


def rollout_pieces(number: int, repeats: int) -> dict:
    rng = np.random.default_rng(0)
    obs = rng.standard_normal((1, 111)) * 3
    agent = GaussianActorCritic(111, 8)
    norm = agent.obs_normalizer
    fast = norm.rollout(1)
    out32 = np.empty((1, 111), np.float32)
    x = torch.from_numpy(out32)
    actor = agent.rollout_actor(x)
    scaler = RewardScaler(1, 0.99, 10.0)
    reward, done = np.array([0.5]), np.array([False])
    pieces = {}
    pieces["normaliser_module_us"] = 1e6 * best_time(lambda: (norm.update(obs), norm.normalize_np(obs)), number,
                                                     repeats)
    pieces["normaliser_rollout_us"] = 1e6 * best_time(lambda: (fast.update(obs), fast.normalize_into(obs, out32)),
                                                      number, repeats)
    pieces["reward_scaler_array_us"] = 1e6 * best_time(lambda: scaler(reward, done), number, repeats)
    pieces["reward_scaler_scalar_us"] = 1e6 * best_time(lambda: scaler.scale_one(0.5, False), number, repeats)
    agents = {"ppo": agent, "mikt_1": mikt_agent("centipede-eight", ["centipede-six"]),
              "mikt_2": mikt_agent("centipede-eight", ["centipede-four", "centipede-six"])}
    with torch.inference_mode():
        for name, ag in agents.items():
            xin = x if name == "ppo" else torch.zeros(1, ag.obs_normalizer.mean.shape[0])
            run = ag.rollout_actor(xin)
            pieces[f"forward_{name}_module_us"] = 1e6 * best_time(
                lambda a=ag, i=xin: a.action_mean(i).numpy(), number, repeats)
            pieces[f"forward_{name}_rollout_us"] = 1e6 * best_time(lambda r=run: r().numpy(), number, repeats)
    del actor
    return pieces


def update_pieces(repeats: int, compiled: bool) -> dict:
    """One minibatch step (loss, backward, clip, Adam), eager and compiled, alternated; compile time apart."""
    setups = {"ppo_ant": ("ant", None), "mikt_1_eight": ("centipede-eight", ["centipede-six"]),
              "mikt_2_eight": ("centipede-eight", ["centipede-four", "centipede-six"])}
    out = {}
    for name, (env, teachers) in setups.items():
        trainers, batches, first = {}, {}, {}
        for comp in (False, True) if compiled else (False,):
            torch.manual_seed(0)
            agent = GaussianActorCritic(111, 8) if teachers is None else mikt_agent(env, teachers)
            config = PPOConfig(n_steps=256, epochs=1, compile_loss=comp, kl_coef=0.0 if teachers is None else 0.05)
            trainer = PPOTrainer(agent, lambda e=env: make_env(e), config, 10**6, 0)
            if teachers is None and not comp:  # the plain actor-critic also has its gradient by hand
                torch.manual_seed(0)
                hand = PPOTrainer(GaussianActorCritic(111, 8), lambda e=env: make_env(e),
                                  config.model_copy(update={"gradients": "by-hand"}), 10**6, 0)
                hand.update(batches.setdefault("by-hand", hand._values_and_targets(hand.collect()[0])))
                trainers["by-hand"] = hand
            batches[comp] = trainer._values_and_targets(trainer.collect()[0])  # by hand: its own, before
            t = time.perf_counter()
            trainer.update(batches[comp])  # compiles (compiled) / warms up (eager)
            first[comp] = time.perf_counter() - t
            trainers[comp] = trainer
        best = dict.fromkeys(trainers, float("inf"))
        for _ in range(repeats):
            for comp, trainer in trainers.items():
                best[comp] = min(best[comp], best_time(lambda tr=trainer, b=batches[comp]: tr.update(b), 3, 1) / 4)
        row = {"eager_us_per_minibatch": 1e6 * best[False]}
        if "by-hand" in best:
            row["by_hand_us_per_minibatch"] = 1e6 * best["by-hand"]
        if compiled:
            row["compiled_us_per_minibatch"] = 1e6 * best[True]
            row["compile_s"] = first[True] - first[False]
        out[name] = row
        for trainer in trainers.values():
            trainer.close()
    return out


# --- the report -------------------------------------------------------------------------------------------
def ratios(res: dict) -> dict:
    r: dict = {}
    phys = 1e6 / res["physics_ant_us"]
    r["rollout_vs_physics"] = res["in_process"]["engine"]["rollout_steps_per_sec"] / phys
    if "physics_replay_ant_us" in res:
        r["rollout_vs_physics_same_steps"] = (res["in_process"]["engine"]["rollout_steps_per_sec"]
                                              * res["physics_replay_ant_us"] / 1e6)
    r["ppo_vs_sb3"] = res["in_process"]["engine"]["steps_per_sec"] / res["in_process"]["sb3"]["steps_per_sec"]
    if "engine_compiled" in res["in_process"]:
        r["ppo_compiled_vs_sb3"] = (res["in_process"]["engine_compiled"]["steps_per_sec"]
                                    / res["in_process"]["sb3"]["steps_per_sec"])
    if "engine_by_hand" in res["in_process"]:
        r["ppo_by_hand_vs_sb3"] = (res["in_process"]["engine_by_hand"]["steps_per_sec"]
                                   / res["in_process"]["sb3"]["steps_per_sec"])
    wp = res.get("whole_process")
    if wp:
        r["teacher_vs_sb3_script"] = wp["sb3_ppo_script"]["wall_s"] / wp["mikt_teacher_train_ant"]["wall_s"]
        base = wp["ppo_from_scratch_eight"]["wall_s"]
        r["one_teacher_vs_ppo"] = wp["one_teacher_six_to_eight"]["wall_s"] / base
        r["two_teachers_vs_ppo"] = wp["two_teachers_four_six_to_eight"]["wall_s"] / base
        if "ppo_from_scratch_eight_autograd" in wp:  # the same PPO with autograd's update, as before by-hand
            autograd = wp["ppo_from_scratch_eight_autograd"]["wall_s"]
            r["one_teacher_vs_ppo_autograd"] = wp["one_teacher_six_to_eight"]["wall_s"] / autograd
            r["two_teachers_vs_ppo_autograd"] = wp["two_teachers_four_six_to_eight"]["wall_s"] / autograd
    if "seeds_together" in res:
        r["seeds_together_vs_separate"] = res["seeds_together"]["separate_s"] / res["seeds_together"]["together_s"]
    study = res.get("study_speed")
    if study:
        for name in ("mikt_1", "mikt_2"):
            r[f"study_{name}_vs_ppo"] = study["ppo"]["steps_per_sec"] / study[name]["steps_per_sec"]
    return r


def fmt(x: float, digits: int = 0) -> str:
    return f"{x:,.{digits}f}"


def markdown(res: dict) -> str:
    r, ip = res["ratios"], res["in_process"]
    eng, sb3 = ip["engine"], ip["sb3"]
    phys_rate = 1e6 / res["physics_ant_us"]
    lines = [
        "<!-- generated by benchmarks/throughput.py; do not edit by hand -->",
        f"Measured {res['date']} with `{res['command']}` (commit {res['commit']}, {res['machine']}, Python "
        f"{res['python']}, torch {res['torch']}, 1 thread; best of {res['repeats']} repeats, systems alternated"
        f"{'; QUICK smoke run, not a measurement' if res['quick'] else ''}).",
        "",
        "| measure | this engine | reference | ratio | target |",
        "|---|---|---|---|---|",
        "| PPO rollout (Ant, `collect`) vs the physics-only limit (`mj_step` × 5) | "
        f"{fmt(eng['rollout_steps_per_sec'])} steps/s | {fmt(phys_rate)} steps/s | {r['rollout_vs_physics']:.2f} | "
        f"≥ {TARGETS['rollout_vs_physics']:.2f} |",
        *([f"| the same rollout vs the physics of its very steps (its actions replayed through `mj_step` × 5) | "
           f"{fmt(eng['rollout_steps_per_sec'])} steps/s | {fmt(1e6 / res['physics_replay_ant_us'])} steps/s | "
           f"{r['rollout_vs_physics_same_steps']:.2f} | ≥ {TARGETS['rollout_vs_physics']:.2f} |"]
          if "physics_replay_ant_us" in res else []),
        f"| PPO in process vs Stable-Baselines3 (Ant, {fmt(eng['steps'])} steps) | {fmt(eng['steps_per_sec'])} steps/s "
        f"| {fmt(sb3['steps_per_sec'])} steps/s | {r['ppo_vs_sb3']:.2f}× | ≥ {TARGETS['ppo_vs_sb3']}× |",
    ]
    comp = ip.get("engine_compiled")
    if comp:
        lines.append(f"| the same, compiled update (autograd's default from {AUTO_MIN_STEPS:,} steps, e.g. the "
                     f"paper's 2M) | {fmt(comp['steps_per_sec'])} steps/s | {fmt(sb3['steps_per_sec'])} steps/s | "
                     f"{r['ppo_compiled_vs_sb3']:.2f}× | ≥ {TARGETS['ppo_vs_sb3']}× |")
    hand = ip.get("engine_by_hand")
    if hand:
        lines.append(f"| the same, gradient by hand (the default of PPO, VPG, MLPP and teacher runs alone) | "
                     f"{fmt(hand['steps_per_sec'])} steps/s | {fmt(sb3['steps_per_sec'])} steps/s | "
                     f"{r['ppo_by_hand_vs_sb3']:.2f}× | ≥ {TARGETS['ppo_vs_sb3']}× |")
    wp = res.get("whole_process")
    if wp:
        base = wp["ppo_from_scratch_eight"]["wall_s"]
        lines += [
            f"| whole process: `mikt teacher train ant` vs an SB3 PPO script ({fmt(res['steps_teacher'])} steps) | "
            f"{wp['mikt_teacher_train_ant']['wall_s']:.1f} s | {wp['sb3_ppo_script']['wall_s']:.1f} s | "
            f"{r['teacher_vs_sb3_script']:.2f}× faster | ≥ {TARGETS['teacher_vs_sb3_script']}× |",
            f"| whole process: one-teacher transfer (six → eight) vs PPO from scratch ({fmt(res['steps_transfer'])} "
            f"steps) | {wp['one_teacher_six_to_eight']['wall_s']:.1f} s | {base:.1f} s | "
            f"{r['one_teacher_vs_ppo']:.2f}× the time | ≤ {TARGETS['one_teacher_vs_ppo']}× |",
            f"| whole process: two-teacher transfer (four + six → eight) vs PPO from scratch | "
            f"{wp['two_teachers_four_six_to_eight']['wall_s']:.1f} s | {base:.1f} s | "
            f"{r['two_teachers_vs_ppo']:.2f}× the time | ≤ {TARGETS['two_teachers_vs_ppo']}× |",
        ]
        if "one_teacher_vs_ppo_autograd" in r:
            autograd = wp["ppo_from_scratch_eight_autograd"]["wall_s"]
            lines += [
                f"| the same two against PPO from scratch with autograd's update (`--ppo gradients=autograd`, "
                f"{autograd:.1f} s) | one teacher {wp['one_teacher_six_to_eight']['wall_s']:.1f} s, two "
                f"{wp['two_teachers_four_six_to_eight']['wall_s']:.1f} s | {autograd:.1f} s | "
                f"{r['one_teacher_vs_ppo_autograd']:.2f}× and {r['two_teachers_vs_ppo_autograd']:.2f}× the time | "
                f"≤ {TARGETS['one_teacher_vs_ppo']}× and ≤ {TARGETS['two_teachers_vs_ppo']}× |",
            ]
    if "seeds_together" in res:
        lines += seeds_together_markdown(res)
    if wp:
        lines += ["", "In the whole-process runs, teacher training and PPO from scratch have their gradient by hand "
                  f"(the default); the transfers are below {AUTO_MIN_STEPS:,} steps, so their update is autograd's "
                  "eager one (auto). Each command's stderr names the path and its card records it."]
    study = res.get("study_speed")
    if study:
        ppo = study["ppo"]
        lines += ["", f"At a study's settings (in process, centipede-eight, compiled update as from {AUTO_MIN_STEPS:,} "
                  f"steps, {fmt(ppo['steps'])} timed steps, the teachers active and coupled as in the first 90 % of a "
                  f"run): PPO from scratch {fmt(ppo['steps_per_sec'])} steps/s; one teacher (six) "
                  f"{fmt(study['mikt_1']['steps_per_sec'])} steps/s, {r['study_mikt_1_vs_ppo']:.2f}× PPO's time "
                  f"(target {TARGETS['one_teacher_vs_ppo']}×); two teachers (four + six) "
                  f"{fmt(study['mikt_2']['steps_per_sec'])} steps/s, {r['study_mikt_2_vs_ppo']:.2f}× "
                  f"(target {TARGETS['two_teachers_vs_ppo']}×). Per env step (µs; env / inference / update): "
                  + "; ".join(f"{name} {u['env']:.0f} / {u['inference']:.0f} / {u['update']:.0f}"
                              for name, u in ((n, study[n]["us_per_step"]) for n in STUDY_RUNS)) + "."]
    us = eng["us_per_step"]
    compiled_update = f", {comp['us_per_step']['update']:.0f} compiled" if comp else ""
    if hand:
        compiled_update += f", {hand['us_per_step']['update']:.0f} by hand"
    lines += ["", "**Where this engine's PPO step goes** (Ant, in process, µs per env step, the engine's own timers): "
              f"env {us['env']:.0f} (physics alone: {res['physics_ant_us']:.0f} standing, "
              f"{res.get('physics_replay_ant_us', float('nan')):.0f} on the same steps), inference "
              f"{us['inference']:.0f}, rest of the rollout {us['rollout_other']:.0f}, update {us['update']:.0f} "
              f"(eager){compiled_update}. SB3 spends "
              f"{1e6 / sb3['steps_per_sec']:.0f} µs per step in all; "
              f"{TARGETS['ppo_vs_sb3']}× SB3 leaves {1e6 / sb3['steps_per_sec'] / TARGETS['ppo_vs_sb3']:.0f} µs.", ""]
    lines += ["| piece (µs per call, min of repeats) | gymnasium / module path | lean / rollout path |",
              "|---|---|---|"]
    for env, row in res["pieces"]["env"].items():
        lines.append(f"| {env} env step (physics alone {row['physics_us']:.0f}) | {row['step_gymnasium_us']:.0f} | "
                     f"{row['step_lean_us']:.0f} |")
    p = res["pieces"]["rollout"]
    lines += [
        f"| observation normaliser, update + normalise (111 dims) | {p['normaliser_module_us']:.1f} | "
        f"{p['normaliser_rollout_us']:.1f} |",
        f"| reward scaler (1 env) | {p['reward_scaler_array_us']:.1f} | {p['reward_scaler_scalar_us']:.1f} |",
        f"| policy forward, batch of one, PPO (Ant) | {p['forward_ppo_module_us']:.1f} | "
        f"{p['forward_ppo_rollout_us']:.1f} |",
        f"| policy forward, batch of one, MIKT 1 teacher (eight) | {p['forward_mikt_1_module_us']:.1f} | "
        f"{p['forward_mikt_1_rollout_us']:.1f} |",
        f"| policy forward, batch of one, MIKT 2 teachers (eight) | {p['forward_mikt_2_module_us']:.1f} | "
        f"{p['forward_mikt_2_rollout_us']:.1f} |",
        "",
        "| minibatch update step (loss, backward, clip, Adam; 64 samples) | eager µs | compiled µs | compile s | "
        "by hand µs |",
        "|---|---|---|---|---|",
    ]
    labels = {"ppo_ant": "PPO, Ant", "mikt_1_eight": "MIKT 1 teacher (six → eight)",
              "mikt_2_eight": "MIKT 2 teachers (four + six → eight)"}
    for name, row in res["pieces"]["update"].items():
        comp = (f"{row['compiled_us_per_minibatch']:.0f} | {row['compile_s']:.0f}" if "compiled_us_per_minibatch" in row
                else "— | —")
        by_hand = f"{row['by_hand_us_per_minibatch']:.0f}" if "by_hand_us_per_minibatch" in row else "—"
        lines.append(f"| {labels[name]} | {row['eager_us_per_minibatch']:.0f} | {comp} | {by_hand} |")
    upd = res["pieces"]["update"]
    if "compiled_us_per_minibatch" in upd["ppo_ant"]:
        def per_step(name: str, key: str) -> float:
            return upd[name][key] * 320 / 2048  # 10 epochs × 32 minibatches per 2,048-step rollout

        lines += ["", "Update per env step (320 minibatches per 2,048 steps): PPO "
                  f"{per_step('ppo_ant', 'eager_us_per_minibatch'):.0f} µs eager, "
                  f"{per_step('ppo_ant', 'compiled_us_per_minibatch'):.0f} µs compiled; MIKT with 2 teachers "
                  f"{per_step('mikt_2_eight', 'eager_us_per_minibatch'):.0f} µs eager, "
                  f"{per_step('mikt_2_eight', 'compiled_us_per_minibatch'):.0f} µs compiled. "
                  "Runs from 500,000 steps compile by default (`--compile/--no-compile` to choose)."]
    return "\n".join(lines) + "\n"


def commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny sizes, one repeat, no compile: a smoke run")
    parser.add_argument("--repeats", type=int, default=None, help="best of N (default 2; --quick 1)")
    parser.add_argument("--steps", type=int, default=None, help="in-process timed steps (default 20,480)")
    parser.add_argument("--no-whole-process", action="store_true", help="skip part 3 (the subprocess runs)")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results",
                        help="folder for throughput.json and throughput.md")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--only", choices=["seeds-together"], default=None,
                        help="measure one part alone (written to throughput-PART.json/.md beside the full run's)")
    args = parser.parse_args(argv)
    quick = args.quick
    repeats = args.repeats or (1 if quick else 2)
    steps = args.steps or (2048 if quick else 20480)
    steps_teacher, steps_transfer = (2048, 2048) if quick else (30720, 20480)
    number = 50 if quick else 2000
    torch.set_num_threads(1)
    warnings.filterwarnings("ignore")
    if str(ROOT / "benchmarks") not in sys.path:
        sys.path.insert(0, str(ROOT / "benchmarks"))
    command = shlex.join(["python", "benchmarks/throughput.py", *(argv if argv is not None else sys.argv[1:])])
    res: dict = {"date": dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC"), "command": command,
                 "commit": commit(), "machine": f"{platform.machine()}, {os.cpu_count()} CPUs",
                 "python": sys.version.split()[0], "torch": torch.__version__, "repeats": repeats, "quick": quick,
                 "steps_teacher": steps_teacher, "steps_transfer": steps_transfer}
    t_start = time.perf_counter()
    if args.only:
        return only_seeds_together(res, args, repeats, 2048 if quick else 20480, t_start)
    res["physics_ant_us"] = physics_us("ant", number * 2, repeats + 2)
    res["physics_replay_ant_us"] = min(physics_replay_us(steps, args.seed) for _ in range(repeats))
    runs: dict[str, list[dict]] = {"engine": [], "engine_by_hand": [], "sb3": []} | (
        {} if quick else {"engine_compiled": []})
    for _ in range(repeats):
        runs["engine"].append(engine_run(steps, args.seed))
        runs["engine_by_hand"].append(engine_run(steps, args.seed, gradients="by-hand"))
        if not quick:
            runs["engine_compiled"].append(engine_run(steps, args.seed, compile_loss=True))
        runs["sb3"].append(sb3_run(steps, args.seed))
    res["in_process"] = {k: min(v, key=lambda r: r["wall_s"]) for k, v in runs.items()}
    if not quick:  # a study's runs: 2M steps on a centipede, so compiled (auto), PPO against MIKT
        study: dict[str, list[dict]] = {name: [] for name in STUDY_RUNS}
        for _ in range(repeats):
            for name, teachers in STUDY_RUNS.items():
                study[name].append(engine_run(steps, args.seed, True, "centipede-eight", teachers))
        res["study_speed"] = {k: min(v, key=lambda r: r["wall_s"]) for k, v in study.items()}
    res["pieces"] = {"env": env_pieces(number, repeats + 2), "rollout": rollout_pieces(number, repeats + 2),
                     "update": update_pieces(repeats * 3, compiled=not quick)}
    if not args.no_whole_process:
        with tempfile.TemporaryDirectory() as registry:
            env = process_env(registry)
            res["whole_process"] = whole_process(process_commands(steps_teacher, steps_transfer), repeats, env)
            res["seeds_together"] = seeds_together(steps_transfer, 2 if quick else 5, repeats, env)
            res["seeds_together"]["update"] = together_update(2 if quick else 5, repeats, 128 if quick else 1024)
    res["ratios"] = ratios(res)
    res["wall_s"] = time.perf_counter() - t_start
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "throughput.json").write_text(json.dumps(res, indent=1) + "\n")
    page = markdown(res)
    (args.out / "throughput.md").write_text(page)
    print(page)
    print(f"({res['wall_s']:.0f} s; wrote {args.out / 'throughput.json'} and {args.out / 'throughput.md'})")
    return res


def process_env(registry: str) -> dict[str, str]:
    """Subprocesses on a registry of their own holding the packaged teachers, running this checkout's code."""
    shutil.copytree(ROOT / "registry" / "teachers", Path(registry) / "teachers")
    return {**os.environ, "MIKT_REGISTRY": registry,
            "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])}


def only_seeds_together(res: dict, args: argparse.Namespace, repeats: int, steps: int, t_start: float) -> dict:
    with tempfile.TemporaryDirectory() as registry:
        res["seeds_together"] = seeds_together(steps, 2 if args.quick else 5, repeats, process_env(registry))
    res["seeds_together"]["update"] = together_update(2 if args.quick else 5, repeats, 128 if args.quick else 1024)
    res["ratios"] = {"seeds_together_vs_separate": res["seeds_together"]["separate_s"]
                     / res["seeds_together"]["together_s"]}
    res["wall_s"] = time.perf_counter() - t_start
    page = "\n".join([
        "<!-- generated by benchmarks/throughput.py --only seeds-together; do not edit by hand -->",
        f"Measured {res['date']} with `{res['command']}` (commit {res['commit']}, {res['machine']}, Python "
        f"{res['python']}, torch {res['torch']}; best of {res['repeats']} repeats, the sides alternated"
        f"{'; QUICK smoke run, not a measurement' if res['quick'] else ''}).", "",
        "| measure | this engine | reference | ratio | target |", "|---|---|---|---|---|",
        *seeds_together_markdown(res)]) + "\n"
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "throughput-seeds-together.json").write_text(json.dumps(res, indent=1) + "\n")
    (args.out / "throughput-seeds-together.md").write_text(page)
    print(page)
    return res


if __name__ == "__main__":
    main()
