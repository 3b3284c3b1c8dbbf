"""Resolves what `eval` and `inspect` are pointed at: a teacher reference or a run's student."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

from miktcli.errors import MiktError
from miktcli.policies import ActorCritic


def _agent_from_checkpoint(run, registry: Path) -> ActorCritic:
    from miktcli.methods import build_agent

    agent = build_agent(run, registry)
    _, tensors = run.load_checkpoint()
    agent.load_state_dict({k[len("agent."):]: v for k, v in tensors.items() if k.startswith("agent.")})
    return agent


class LoadedPolicy(NamedTuple):
    policy: ActorCritic
    env: str
    label: str
    clip_actions: bool  # how actions reached the env in training: evaluate the same way


def load_run_policy(registry: Path, run_id: str, with_teacher: bool) -> LoadedPolicy:
    """A run's policy: the saved teacher-free student, or (with_teacher) the MIKT agent from its checkpoint."""
    from miktcli.ppo import PPOConfig
    from miktcli.registry.runs import open_run
    from miktcli.registry.teachers import load_policy_file
    from miktcli.workflows.transfer import student_path

    run = open_run(registry, run_id)
    if with_teacher:
        if run.card.method != "mikt":
            raise MiktError(f"run '{run.id}' ({run.card.method}) has no teacher to evaluate with")
        agent = _agent_from_checkpoint(run, registry)
        agent.teacher_active = True  # also after the three-phase schedule dropped it: its learned weights
        label = f"{run.id} student + teacher"
    elif student_path(run).exists():
        _, agent = load_policy_file(student_path(run))
        label = f"{run.id} student"
    else:
        # An interrupted or running run: its last checkpoint, teacher-free.
        agent = _agent_from_checkpoint(run, registry)
        if hasattr(agent, "student_only"):
            agent = agent.student_only()
        label = f"{run.id} student (checkpoint at {run.card.steps_done} steps)"
    agent.obs_normalizer.frozen = True
    agent.eval()
    clip = PPOConfig.from_record(run.card.config.get("ppo", {})).clip_actions_for_env
    return LoadedPolicy(agent, run.card.env, label, clip)


def load_policy(registry: Path, target: str, with_teacher: bool = False) -> LoadedPolicy:
    from miktcli.registry.runs import RUN_TARGET_RE
    from miktcli.registry.teachers import load_teacher

    if RUN_TARGET_RE.match(target):
        return load_run_policy(registry, target, with_teacher)
    if with_teacher:
        raise MiktError("--with-teacher applies to runs (runN), not to teachers")
    teacher = load_teacher(registry, target)
    return LoadedPolicy(teacher.policy, teacher.card.env, teacher.card.ref, teacher.card.clip_actions_for_env)
