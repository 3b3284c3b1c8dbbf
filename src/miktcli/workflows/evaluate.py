"""Evaluation as library calls: resolve what `eval` and `inspect` point at (a teacher or a run's student),
and run it for a number of episodes the way it was trained (raw or clipped actions)."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

from miktcli.engine.episodes import evaluate_policy, evaluation_summary  # noqa: F401 - the workflows' names
from miktcli.engine.policies import TEACHER_FREE, ActorCritic
from miktcli.engine.ppo import iterations_for
from miktcli.errors import MiktError
from miktcli.methods import get_method
from miktcli.registry.carried import ResolvedEnv, resolve_teacher_env
from miktcli.registry.runs import RUN_TARGET_RE, open_run
from miktcli.registry.teachers import load_policy_file, load_teacher
from miktcli.workflows.session import (
    EVAL_SEED_OFFSET,
    agent_at_checkpoint,
    agent_from_checkpoint,
    evaluate_handover,
    run_env,
)

DROP_CHECKPOINT = f"before-{TEACHER_FREE}"  # kept just before the teacher drop (Job._phase_change)


class LoadedPolicy(NamedTuple):
    policy: ActorCritic
    env: str  # a SpecName: the environment as resolved (the spec folders, or the copy the run or teacher carries)
    label: str  # says so when a carried copy stands in for the spec folders
    clip_actions: bool  # how actions reached the env in training: evaluate the same way


def _label(label: str, env: ResolvedEnv) -> str:
    return label if env.copy_of is None else f"{label} (environment: the copy {env.copy_of} carries)"


def load_run_policy(registry: Path, run_id: str, with_teacher: bool) -> LoadedPolicy:
    """A run's policy: the saved teacher-free student, or (with_teacher) the agent with its teachers, from
    its checkpoint."""
    run = open_run(registry, run_id)
    env = run_env(run, "cannot evaluate")
    method = get_method(run.card.method)
    if with_teacher:
        if method.with_teachers is None:
            raise MiktError(f"run '{run.id}' ({run.card.method}) has no teacher to evaluate with")
        agent = method.with_teachers(agent_from_checkpoint(run, registry, env.spec))
        label = f"{run.id} student + teacher"
    elif run.student_path.exists():
        card, agent = load_policy_file(run.student_path)
        if (card.source_run, card.env) != (run.id, run.card.env):  # another run's or a teacher's file
            raise MiktError(f"{run.student_path}: the file is {card.ref} on {card.env}, not {run.id}'s student "
                            f"on {run.card.env} (copied or tampered)")
        label = f"{run.id} student"
    else:  # an interrupted or running run: its last checkpoint, teacher-free
        agent = method.student(agent_from_checkpoint(run, registry, env.spec))
        label = f"{run.id} student (checkpoint at {run.card.steps_done} steps)"
    agent.obs_normalizer.frozen = True
    agent.eval()
    return LoadedPolicy(agent, env.name, _label(label, env), run.card.config.ppo.clip_actions_for_env)


def load_policy(registry: Path, target: str, with_teacher: bool = False) -> LoadedPolicy:
    """`target` is a run (runN, last) or a teacher reference (NAME, NAME@vN)."""
    if RUN_TARGET_RE.fullmatch(target):
        return load_run_policy(registry, target, with_teacher)
    if with_teacher:
        raise MiktError("--with-teacher applies to runs (runN), not to teachers")
    teacher = load_teacher(registry, target)
    env = resolve_teacher_env(teacher.card, teacher.carried, "cannot evaluate")
    return LoadedPolicy(teacher.policy, env.name, _label(teacher.card.ref, env), teacher.card.clip_actions_for_env)



def measure_handover(registry: Path, run_id: str, episodes: int) -> dict:
    """The hand-over at the teacher drop measured again, on `episodes` evaluation episodes: from the run's
    checkpoint kept just before the drop, the mixed policy, then the run's own hand-over and the teacher-free
    student, as training measured it (the same function, seeds and actions), so with the run's own episode
    count the numbers are the card's. More episodes narrow a 10-episode record: the first episodes are the
    card's, the rest continue its seeds."""
    run = open_run(registry, run_id)
    method = get_method(run.card.method)
    if method.with_teachers is None:
        raise MiktError(f"run '{run.id}' ({run.card.method}) has no teachers, so no hand-over")
    kept = run.kept_checkpoints()
    if DROP_CHECKPOINT not in kept:
        raise MiktError(f"run '{run.id}' kept no checkpoint '{DROP_CHECKPOINT}'" +
                        (f"; it kept: {', '.join(kept)}" if kept else ""),
                        hint="a run keeps it when it passes the drop; a study's snapshots carry no checkpoints")
    env = run_env(run, "cannot evaluate")
    agent, ckpt = agent_at_checkpoint(run, registry, env.spec, run.kept_checkpoint_path(DROP_CHECKPOINT))
    iterations = iterations_for(run.card.total_steps, run.card.config.ppo)
    agent.restore_progress((ckpt.iteration - 1) / iterations)  # where training had the schedule
    record = evaluate_handover(agent, method, env.name, episodes, EVAL_SEED_OFFSET + run.card.seed,
                               run.card.config.ppo.clip_actions_for_env, ckpt.iteration / iterations)
    return {"run": run.id, "env": env.name, "handover": (run.card.config.options or {}).get("handover"),
            "at_step": ckpt.steps, "episodes": episodes, **record, "recorded": run.card.result.get("handover")}
