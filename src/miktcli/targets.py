"""Resolves what `eval` and `inspect` are pointed at: a teacher reference or a run's student."""

from __future__ import annotations

from pathlib import Path

from miktcli.errors import MiktError
from miktcli.policies import ActorCritic


def load_run_policy(registry: Path, run_id: str, with_teacher: bool) -> tuple[ActorCritic, str, str]:
    """A run's policy: the saved teacher-free student, or (with_teacher) the MIKT agent from its checkpoint."""
    from miktcli.methods import build_agent
    from miktcli.runs import open_run
    from miktcli.teachers import check_card_against_tensors, read_teacher_card
    from miktcli.transfer import student_path

    run = open_run(registry, run_id)
    if with_teacher:
        if run.card.method != "mikt":
            raise MiktError(f"run '{run_id}' ({run.card.method}) has no teacher to evaluate with")
        agent = build_agent(run, registry)
        _, tensors = run.load_checkpoint()
        agent.load_state_dict({k[len("agent."):]: v for k, v in tensors.items() if k.startswith("agent.")})
        agent.teacher_active = True  # also after the three-phase schedule dropped it: its learned weights
        label = f"{run_id} student + teacher"
    elif student_path(run).exists():
        from miktcli.checkpoint import read_tensors, verify_sha
        from miktcli.policies import GaussianActorCritic

        path = student_path(run)
        card = read_teacher_card(path)
        tensors = read_tensors(path)
        check_card_against_tensors(path, card, tensors)
        verify_sha(path, tensors, card.tensors_sha256)
        agent = GaussianActorCritic(card.obs_dim, card.act_dim, card.pi_hidden, card.vf_hidden)
        agent.load_state_dict(tensors)
        label = f"{run_id} student"
    else:
        # An interrupted or running run: its last checkpoint, teacher-free.
        agent = build_agent(run, registry)
        _, tensors = run.load_checkpoint()
        agent.load_state_dict({k[len("agent."):]: v for k, v in tensors.items() if k.startswith("agent.")})
        if hasattr(agent, "student_only"):
            agent = agent.student_only()
        label = f"{run_id} student (checkpoint at {run.card.steps_done} steps)"
    agent.obs_normalizer.frozen = True
    agent.eval()
    return agent, run.card.env, label


def load_policy(registry: Path, target: str, with_teacher: bool = False) -> tuple[ActorCritic, str, str]:
    from miktcli.runs import RUN_TARGET_RE
    from miktcli.teachers import load_teacher

    if RUN_TARGET_RE.match(target):
        return load_run_policy(registry, target, with_teacher)
    if with_teacher:
        raise MiktError("--with-teacher applies to runs (runN), not to teachers")
    teacher = load_teacher(registry, target)
    return teacher.policy, teacher.card.env, teacher.card.ref
