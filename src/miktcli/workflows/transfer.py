"""`mikt transfer` as a library: checks teachers against the target, plans the run, finishes it."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import torch
from pydantic import ValidationError

from miktcli.envs import load_spec, make_env
from miktcli.errors import MiktError, describe_validation_error
from miktcli.evaluation import evaluate
from miktcli.methods.mikt import MiktConfig
from miktcli.policies import ActorCritic, GaussianActorCritic
from miktcli.ppo import PPOConfig
from miktcli.registry.cards import TeacherCard, TeacherRef, now
from miktcli.registry.files import save_with_card
from miktcli.registry.runs import Run
from miktcli.registry.teachers import Teacher, load_teacher

DEFAULT_KL_COEF = {"mikt": 0.05, "mlpp": 0.0, "vpg": 0.0}


def check_teachers(
    teachers: list[Teacher], encoder_widths: list[int] | None, hidden: list[int] | None
) -> list[int]:
    """The encoder width of each teacher is its card's state dimension; anything contradicting it fails here.

    Returns the student's hidden sizes (those of the teachers, which must agree)."""
    if encoder_widths:
        if len(encoder_widths) != len(teachers):
            raise MiktError(f"--encoder-width given {len(encoder_widths)} times for {len(teachers)} teacher(s)")
        for t, width in zip(teachers, encoder_widths, strict=True):
            if width != t.card.obs_dim:
                raise MiktError(f"teacher '{t.card.ref}': its card says state dim {t.card.obs_dim}, "
                                f"--encoder-width asks for {width}")
    first = teachers[0].card
    for t in teachers[1:]:
        if (t.card.pi_hidden, t.card.vf_hidden) != (first.pi_hidden, first.vf_hidden):
            raise MiktError(f"teacher '{t.card.ref}': hidden sizes {t.card.pi_hidden}/{t.card.vf_hidden} differ "
                            f"from teacher '{first.ref}' ({first.pi_hidden}/{first.vf_hidden})")
    if hidden is not None and (hidden != first.pi_hidden or hidden != first.vf_hidden):
        raise MiktError(f"teacher '{first.ref}': its card says hidden sizes {first.pi_hidden} (policy) / "
                        f"{first.vf_hidden} (value), --hidden asks for {hidden}")
    return first.pi_hidden


def teacher_ref(t: Teacher) -> TeacherRef:
    return TeacherRef(name=t.card.name, version=t.card.version, sha256=t.card.tensors_sha256,
                      obs_dim=t.card.obs_dim, env=t.card.env)


def plan_transfer(
    registry: Path, *, env: str, method: str, teacher_refs: list[str], ppo: PPOConfig, mikt: MiktConfig,
    encoder_widths: list[int] | None = None, hidden: list[int] | None = None,
) -> tuple[dict[str, Any], list[TeacherRef]]:
    """Validate everything a transfer needs before a run exists; returns the run config and teachers."""
    spec = load_spec(env)
    if method == "vpg":
        if teacher_refs:
            raise MiktError("--method vpg trains from scratch: drop --from")
        sizes = hidden or [64, 64]
        return {"ppo": ppo.model_dump(), "pi_hidden": sizes, "vf_hidden": sizes}, []
    if not teacher_refs:
        raise MiktError(f"--method {method} needs a teacher: --from NAME or NAME@vN")
    if method == "mlpp" and len(teacher_refs) > 1:
        raise MiktError("--method mlpp takes exactly one teacher")
    teachers = [load_teacher(registry, ref) for ref in teacher_refs]
    sizes = check_teachers(teachers, encoder_widths if method == "mikt" else None, hidden)
    config: dict[str, Any] = {"ppo": ppo.model_dump(), "pi_hidden": sizes, "vf_hidden": teachers[0].card.vf_hidden,
                              "target_obs_dim": spec.obs_dim, "target_act_dim": spec.act_dim}
    if method == "mikt":
        config["mikt"] = mikt.model_dump()
        config["encoder_widths"] = [t.card.obs_dim for t in teachers]
    return config, [teacher_ref(t) for t in teachers]


def start_transfer(
    registry: Path, *, to: str, method: str, teacher_refs: list[str], steps: int, seed: int, command: str,
    kl_coef: float | None = None, num_envs: int = 1, mikt_options: dict[str, Any] | None = None,
    encoder_widths: list[int] | None = None, hidden: list[int] | None = None,
) -> Run:
    """Check everything, then create the run folder of a transfer (not yet trained)."""
    from miktcli.workflows.session import new_run

    ppo = PPOConfig(num_envs=num_envs, kl_coef=DEFAULT_KL_COEF[method] if kl_coef is None else kl_coef)
    try:
        mikt = MiktConfig(**(mikt_options or {}))
    except ValidationError as err:
        raise MiktError(f"bad MIKT option: {describe_validation_error(err)}") from err
    config, refs = plan_transfer(registry, env=to, method=method, teacher_refs=teacher_refs, ppo=ppo, mikt=mikt,
                                 encoder_widths=encoder_widths, hidden=hidden)
    return new_run(registry, kind="transfer", env=to, method=method, seed=seed, total_steps=steps, config=config,
                   command=command, teachers=refs)


def load_run_teachers(run: Run, registry: Path) -> list[Teacher]:
    """The exact teacher versions a run was started with; a changed file is refused."""
    teachers = []
    for ref in run.card.teachers:
        t = load_teacher(registry, f"{ref.name}@v{ref.version}")
        if t.card.tensors_sha256 != ref.sha256:
            raise MiktError(f"run '{run.id}': teacher '{t.card.ref}' is not the one the run started with "
                            f"(sha256 {t.card.tensors_sha256[:12]}… vs {ref.sha256[:12]}…)")
        teachers.append(t)
    return teachers


def student_path(run: Run) -> Path:
    return run.path / "student.safetensors"


def save_student(run: Run, student: GaussianActorCritic, final_return: float | None,
                 best_return: float | None, clip_actions: bool) -> TeacherCard:
    """The teacher-free student as a standalone policy file (same format as a teacher)."""
    from miktcli.registry.files import tensors_sha256

    spec = load_spec(run.card.env)
    tensors = {k: v.detach().clone().contiguous() for k, v in student.state_dict().items()}
    card = TeacherCard(
        name=f"{run.id}-student", version=1, env=run.card.env, env_spec=spec.model_dump(), obs_dim=spec.obs_dim,
        act_dim=spec.act_dim, pi_hidden=student.pi.hidden_sizes, vf_hidden=student.vf.hidden_sizes,
        clip_actions_for_env=clip_actions, steps=run.card.steps_done, seed=run.card.seed,
        final_return=final_return, best_return=best_return,
        hyperparameters=run.card.config, packages=run.card.packages, code_version=run.card.code_version,
        source_run=run.id, created=now(), tensors_sha256=tensors_sha256(tensors),
    )
    save_with_card(student_path(run), tensors, card)
    return card


def eval_policy(policy: ActorCritic, env_name: str, episodes: int, seed: int, clip_actions: bool,
                deterministic: bool = True) -> dict[str, float]:
    env = make_env(env_name)
    policy.obs_normalizer.frozen = True
    try:
        res = evaluate(lambda o: policy.act(o, deterministic), env, episodes, seed, clip_actions=clip_actions)
    finally:
        env.close()
    return res.summary()


def finish_transfer(job, episodes: int) -> dict[str, Any]:
    """Save the teacher-free student, evaluate it (and the student with its teacher), complete the run."""
    from miktcli.methods.mikt import MiktActorCritic

    run, agent = job.run, job.agent
    clip = job.config.clip_actions_for_env
    seed = 10_000 + run.card.seed  # evaluation episodes never reuse training seeds
    result: dict[str, Any] = {"final_train_return": job.final_return,
                              "best_train_return": job.best_return if math.isfinite(job.best_return) else None}
    with torch.no_grad():
        if isinstance(agent, MiktActorCritic):
            result["final_mixing"] = {k: v for k, v in agent.diagnostics().items() if k.startswith("p_")}
            agent.teacher_active = True
            result["final_mixing_learned"] = {
                k: v for k, v in agent.diagnostics().items() if k.startswith("p_")}
            result["eval_with_teacher"] = eval_policy(agent, run.card.env, episodes, seed, clip)
            student = agent.student_only()
        else:
            student = agent
        result["eval_without_teacher"] = eval_policy(student, run.card.env, episodes, seed, clip)
    save_student(run, student, job.final_return, result["best_train_return"], clip)
    run.save_card(status="completed", result=result)
    return result
