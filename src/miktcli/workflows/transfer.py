"""Transfers as library calls: check teachers against the target, plan the run, train it, finish it."""

from __future__ import annotations

import math
from collections.abc import Generator
from pathlib import Path
from typing import Any

import torch

from miktcli import limits
from miktcli.engine.compile_choice import decide_compile, decide_gradients
from miktcli.engine.episodes import evaluation_summary
from miktcli.engine.policies import GaussianActorCritic
from miktcli.engine.ppo import PPOConfig
from miktcli.envs.spec import AnySpec
from miktcli.errors import MiktError, TeacherMismatchError
from miktcli.limits import check_count
from miktcli.methods import get_method
from miktcli.methods.mixing import is_mixing_key
from miktcli.registry.cards import RunConfig, TeacherCard, TeacherRef, now
from miktcli.registry.carried import folder_spec_file, resolve_new_env
from miktcli.registry.files import save_with_card, tensors_sha256
from miktcli.registry.runs import Run
from miktcli.registry.teachers import Teacher, load_teacher
from miktcli.workflows.session import EVAL_SEED_OFFSET, Event, Job, Phase, new_run

DEFAULT_HIDDEN = [64, 64]


def check_teachers(
    teachers: list[Teacher], encoder_widths: list[int] | None, hidden: list[int] | None
) -> tuple[list[int], list[int]]:
    """The encoder width of each teacher is its card's state dimension; anything contradicting it fails here.

    Returns the student's hidden sizes (policy, value): those of the teachers, which must agree."""
    if encoder_widths:
        if len(encoder_widths) != len(teachers):
            raise TeacherMismatchError(f"{len(encoder_widths)} encoder width(s) given for {len(teachers)} teacher(s)",
                                       stated="encoder_widths")
        for t, width in zip(teachers, encoder_widths, strict=True):
            if width != t.card.obs_dim:
                raise TeacherMismatchError(f"teacher '{t.card.ref}': state dim {t.card.obs_dim} (from its card), "
                                           f"encoder width {width} requested", stated="encoder_widths")
    first = teachers[0].card
    for t in teachers[1:]:
        if (t.card.pi_hidden, t.card.vf_hidden) != (first.pi_hidden, first.vf_hidden):
            raise TeacherMismatchError(f"teacher '{t.card.ref}': hidden sizes {t.card.pi_hidden}/{t.card.vf_hidden} "
                                       f"differ from teacher '{first.ref}' ({first.pi_hidden}/{first.vf_hidden})",
                                       stated=None)
    if hidden is not None and (hidden != first.pi_hidden or hidden != first.vf_hidden):
        raise TeacherMismatchError(f"teacher '{first.ref}': hidden sizes {first.pi_hidden} (policy) / "
                                   f"{first.vf_hidden} (value) from its card, {hidden} requested", stated="hidden")
    return first.pi_hidden, first.vf_hidden


def teacher_ref(t: Teacher) -> TeacherRef:
    return TeacherRef(name=t.card.name, version=t.card.version, sha256=t.card.tensors_sha256,
                      obs_dim=t.card.obs_dim, env=t.card.env)


def start_transfer(
    registry: Path, *, to: str, method: str, teacher_refs: list[str], steps: int, seed: int, command: str,
    kl_coef: float | None = None, num_envs: int = 1, options: dict[str, Any] | None = None,
    encoder_widths: list[int] | None = None, hidden: list[int] | None = None, compile_loss: bool | None = None,
    eval_episodes: int = 10, ppo_settings: dict[str, Any] | None = None, together: bool = False,
) -> Run:
    """Check everything a transfer needs, then create its run folder (not yet trained).
    compile_loss: True/False as asked, None to decide from the run's size (compile_choice.py). together: the
    run is one of a cell's seeds trained in one process (its update is then autograd's, stacked)."""
    check_count("--eval-episodes", eval_episodes, limits.MAX_EPISODES)
    m = get_method(method)
    m.check_teacher_count(len(teacher_refs))
    parsed = m.parse_options(options)
    # the target from the spec folders, checked first; else from the copy one of the teachers carries
    target = resolve_new_env(to) if folder_spec_file(to) is not None or not teacher_refs else None
    teachers = [load_teacher(registry, ref) for ref in teacher_refs]
    target = target or resolve_new_env(to, [(t.card, t.carried) for t in teachers])
    by_content: dict[str, str] = {}  # tensors' sha256 (verified on load) → the ref that brought them
    for t in teachers:  # the same representation offered twice only splits the student's attention
        sha, ref = t.card.tensors_sha256, t.card.ref
        if sha in by_content:  # by content: one policy imported or copied under two names or versions too
            first = by_content[sha]
            raise MiktError(f"teacher {ref} is given more than once" if first == ref else
                            f"teachers {first} and {ref} hold the same tensors (sha256 {sha[:12]}…): the same "
                            "teacher would be given twice")
        by_content[sha] = ref
    sizes = (check_teachers(teachers, encoder_widths if m.encoder_per_teacher else None, hidden) if teachers
             else (hidden or DEFAULT_HIDDEN, hidden or DEFAULT_HIDDEN))
    settings = dict(ppo_settings or {})
    settings["gradients"] = decide_gradients(settings.get("gradients"), m.plain_actor_critic, together,
                                             compile_asked=compile_loss)
    compiled, reason = decide_compile(compile_loss, steps, by_hand=settings["gradients"] == "by-hand")
    if kl_coef is None and "kl_coef" not in settings:
        kl_coef = m.default_kl_coef
    ppo = PPOConfig.with_settings(settings, num_envs=None if num_envs == 1 else num_envs, kl_coef=kl_coef,
                                  compile_loss=compiled, compile_reason=reason)
    config = RunConfig(ppo=ppo, pi_hidden=sizes[0], vf_hidden=sizes[1],
                       options=None if parsed is None else parsed.model_dump(), eval_episodes=eval_episodes)
    return new_run(registry, kind="transfer", env=to, method=method, seed=seed, total_steps=steps, config=config,
                   command=command, teachers=[teacher_ref(t) for t in teachers], resolved=target)


def train_transfer(run: Run, registry: Path, eval_episodes: int) -> Generator[Event, None, dict[str, Any]]:
    """Train a transfer run to its end (resuming from its checkpoint), then evaluate and save its student.
    Yields each iteration's metrics and the phases; returns the run's result."""
    result = yield from train_transfer_chunk(run, registry, eval_episodes, max_iterations=None)
    assert result is not None
    return result


def train_transfer_chunk(run: Run, registry: Path, eval_episodes: int,
                         max_iterations: int | None) -> Generator[Event, None, dict[str, Any] | None]:
    """Train at most `max_iterations` more iterations (all, for None), checkpointing each; if that reaches the
    end of the run, evaluate and save its student and return the result, else return None (the run stays
    resumable: a distributed study trains its cells in such chunks and hands each chunk's files back)."""
    with Job(run, registry) as job:
        done = 0
        for metrics in job.iterations():
            yield metrics
            done += 1
            if max_iterations is not None and done >= max_iterations \
                    and job.trainer.iteration < job.trainer.num_iterations:
                return None
        yield Phase("evaluate", f"{eval_episodes} episodes")
        return finish_transfer(job, eval_episodes)


def save_student(run: Run, spec: AnySpec, student: GaussianActorCritic, final_return: float | None,
                 best_return: float | None, clip_actions: bool) -> TeacherCard:
    """The teacher-free student on `spec` as a standalone policy file (same format as a teacher; the run's
    folder carries its environment, `teacher add` puts it into the teacher it publishes)."""
    tensors = {k: v.detach().clone().contiguous() for k, v in student.state_dict().items()}
    card = TeacherCard(
        name=f"{run.id}-student", version=1, env=run.card.env, env_spec=spec.model_dump(),
        env_fingerprint=run.card.env_fingerprint, obs_dim=spec.obs_dim,
        act_dim=spec.act_dim, pi_hidden=student.pi.hidden_sizes, vf_hidden=student.vf.hidden_sizes,
        clip_actions_for_env=clip_actions, steps=run.card.steps_done, seed=run.card.seed,
        final_return=final_return, best_return=best_return,
        hyperparameters=run.card.config.model_dump(mode="json"), packages=run.card.packages,
        code_version=run.card.code_version, code_history=run.card.code_history, source_run=run.id, created=now(),
        tensors_sha256=tensors_sha256(tensors),
    )
    save_with_card(run.student_path, tensors, card)
    return card


def mixing_weights(agent) -> dict[str, float]:
    """The student's weights and, with several teachers, each teacher's (names: miktcli.methods.mixing)."""
    return {k: v for k, v in agent.diagnostics().items() if is_mixing_key(k)}


def finish_transfer(job: Job, episodes: int) -> dict[str, Any]:
    """Save the teacher-free student, evaluate it (and the agent with its teachers), complete the run."""
    run, agent, method = job.run, job.agent, job.method
    clip = job.config.clip_actions_for_env
    seed = EVAL_SEED_OFFSET + run.card.seed
    result: dict[str, Any] = {"final_train_return": job.final_return,
                              "best_train_return": job.best_return if math.isfinite(job.best_return) else None}
    for recorded in ("handover", "slowdowns"):  # recorded while training (Job)
        if recorded in run.card.result:
            result[recorded] = run.card.result[recorded]
    with torch.no_grad():
        if method.with_teachers is not None:
            result["final_mixing"] = mixing_weights(agent)  # as trained (1.0 where the schedule dropped them)
            with_teachers = method.with_teachers(agent)
            result["final_mixing_learned"] = mixing_weights(with_teachers)
            result["eval_with_teacher"] = evaluation_summary(with_teachers, job.env.name, episodes, seed, clip)
        student = method.student(agent)
        result["eval_without_teacher"] = evaluation_summary(student, job.env.name, episodes, seed, clip)
    save_student(run, job.spec, student, job.final_return, result["best_train_return"], clip)
    run.save_card(status="completed", result=result)
    return result
