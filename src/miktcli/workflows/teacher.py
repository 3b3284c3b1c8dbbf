"""Teachers as library calls: plan a teacher run, train it to the end, publish the policy; or import one
trained elsewhere."""

from __future__ import annotations

import math
from collections.abc import Generator
from pathlib import Path
from typing import Any

from miktcli.engine.compile_choice import decide_compile, decide_gradients
from miktcli.engine.nets import OBS_CLIP
from miktcli.engine.ppo import PPOConfig
from miktcli.envs.fingerprint import spec_fingerprint
from miktcli.errors import MiktError
from miktcli.registry.cards import RunConfig, TeacherCard, code_version, now, package_versions
from miktcli.registry.carried import EnvFiles, NotCarried, ResolvedEnv, resolve_new_env, teacher_files
from miktcli.registry.importers import read_foreign_policy
from miktcli.registry.runs import Run
from miktcli.registry.teachers import (
    check_name,
    find,
    publish_teacher,
    read_teacher_card,
    resolve,
    versions,
)
from miktcli.workflows.session import Event, Job, Phase, check_registry_writable, new_run


def start_teacher(registry: Path, *, env: str, steps: int, seed: int, command: str, name: str | None = None,
                  num_envs: int = 1, hidden: list[int] | None = None, compile_loss: bool | None = None,
                  ppo_settings: dict[str, Any] | None = None) -> Run:
    """Check everything, then create the run folder of a teacher (PPO from scratch on `env`).
    compile_loss: True/False as asked, None to decide from the run's size (compile_choice.py)."""
    sizes = hidden or [64, 64]
    settings = dict(ppo_settings or {})
    settings["gradients"] = decide_gradients(settings.get("gradients"), plain_actor_critic=True, together=False,
                                             compile_asked=compile_loss)
    compiled, reason = decide_compile(compile_loss, steps, by_hand=settings["gradients"] == "by-hand")
    ppo = PPOConfig.with_settings(settings, num_envs=None if num_envs == 1 else num_envs,
                                  compile_loss=compiled, compile_reason=reason)
    config = RunConfig(ppo=ppo,
                       pi_hidden=sizes, vf_hidden=sizes, teacher_name=check_name(env if name is None else name))
    return new_run(registry, kind="teacher", env=env, method="ppo", seed=seed, total_steps=steps, config=config,
                   command=command)


def train_teacher(run: Run, registry: Path) -> Generator[Event, None, TeacherCard]:
    """Train a teacher run to its end (resuming from its checkpoint) and publish it as the next version of
    its name, carrying its environment. Yields each iteration's metrics; returns the published card."""
    with Job(run, registry) as job:
        yield from job.iterations()
        env, why = env_to_carry(run.card.env, run.card.env_fingerprint, run.path, job.env)
        name = run.card.config.teacher_name or run.card.env
        yield Phase("publish", name if env is not None else f"{name} (without its environment: {why})")
        return publish_teacher_from_job(job, env)


def env_to_carry(name: str, fingerprint: str | None, run_path: Path | None = None,
                 env: ResolvedEnv | None = None) -> tuple[EnvFiles | None, str | None]:
    """The environment files a teacher carries (carried.teacher_files), or None and why not: a teacher is
    published either way, and then needs its spec in a spec folder."""
    if fingerprint is None:
        return None, "its run recorded no fingerprint of it"
    try:
        return teacher_files(name, fingerprint, run_path, env), None
    except (NotCarried, MiktError) as why:  # a file unreadable now: the teacher is still worth publishing
        return None, str(why)
    except OSError as err:
        return None, f"its copy could not be written to the temporary folder: {err.strerror or err}"


def publish_teacher_from_job(job: Job, env: EnvFiles | None = None) -> TeacherCard:
    """Put a finished teacher run's policy into the registry as the next version of its name (carrying
    `env`, the files of its environment)."""
    card, spec = job.run.card, job.spec
    teacher = TeacherCard(
        name=card.config.teacher_name or card.env, version=1, env=card.env, env_spec=spec.model_dump(),
        env_fingerprint=card.env_fingerprint, obs_dim=spec.obs_dim, act_dim=spec.act_dim,
        pi_hidden=card.config.pi_hidden, vf_hidden=card.config.vf_hidden,
        clip_actions_for_env=job.config.clip_actions_for_env,
        steps=job.trainer.global_step, seed=card.seed, final_return=job.final_return,
        best_return=job.best_return if math.isfinite(job.best_return) else None,
        hyperparameters=job.config.model_dump(), packages=card.packages, code_version=card.code_version,
        code_history=card.code_history, source_run=card.run_id, created=now(), tensors_sha256="",
    )
    published = publish_teacher(job.registry, teacher, job.agent, env)
    slowdowns = {"slowdowns": job.run.card.result["slowdowns"]} if "slowdowns" in job.run.card.result else {}
    job.run.save_card(status="completed", result={
        "teacher": published.ref, "final_return": published.final_return, "best_return": published.best_return,
        **slowdowns,
    })
    return published


def add_student_as_teacher(registry: Path, run_id: str, name: str) -> TeacherCard:
    """Publish a completed transfer run's teacher-free student as the next version of teacher `name`, so that
    it can teach in turn (chains such as four → six → eight). Its card keeps the run's provenance: the run,
    the teachers it learned from, the code that trained it, the spec of its env; the file carries the env
    (the run's copy, or the spec folders' if the run has none)."""
    from miktcli.registry.runs import open_run
    from miktcli.registry.teachers import load_policy_file

    run = open_run(registry, run_id)
    if run.card.kind != "transfer":
        raise MiktError(f"run '{run.id}' is a teacher run: its teacher is published already "
                        f"({run.card.result.get('teacher', 'when it completes')})")
    if run.card.status != "completed" or not run.student_path.exists():
        raise MiktError(f"run '{run.id}' is {run.card.status}: only a completed transfer has a student to add",
                        hint=f"finish it first: mikt transfer --resume {run.id}")
    student, policy = load_policy_file(run.student_path)
    if (student.source_run, student.env) != (run.id, run.card.env):
        raise MiktError(f"{run.student_path}: the file is {student.ref} on {student.env}, not {run.id}'s student "
                        f"on {run.card.env} (copied or tampered)")
    check_name(name)
    env, _ = env_to_carry(run.card.env, run.card.env_fingerprint, run.path)
    card = student.model_copy(update={"name": name, "created": now(), "env_fingerprint": run.card.env_fingerprint,
                                      "trained_with": [t.ref for t in run.card.teachers],
                                      "method": run.card.method})
    return publish_teacher(registry, card, policy, env)


def import_teacher(registry: Path, path: Path, *, fmt: str, env: str, name: str | None = None,
                   obs_stats: Path | None = None, activation: str | None = None) -> TeacherCard:
    """Publish a policy trained elsewhere (Stable-Baselines3 zip, CleanRL model) as the next version of a
    teacher, after checking its dims and layers against the env spec; nothing is unpickled."""
    resolved = resolve_new_env(env)
    spec = resolved.spec
    teacher_name = check_name(env if name is None else name)
    if name is None and versions(registry, teacher_name):
        # By default an import is named after its env, as the shipped teachers are: it would silently become
        # what `--from hopper` and `mikt eval hopper` mean.
        latest = find(registry, teacher_name)
        where = "shipped with mikt" if latest.source == "packaged" else f"in {registry}"
        raise MiktError(f"teacher '{teacher_name}' exists already ({latest.ref}, {where}): an import named after "
                        f"its env would replace it wherever `{teacher_name}` is named without a version",
                        hint=f"give it a name of its own (--name {teacher_name}-{fmt}), or --name {teacher_name} "
                             f"to add it as the next version on purpose")
    imported = read_foreign_policy(path, fmt, obs_stats, activation)
    policy = imported.policy
    obs_dim, act_dim = policy.obs_normalizer.mean.shape[0], policy.log_std.shape[0]
    if (obs_dim, act_dim) != (spec.obs_dim, spec.act_dim):
        raise MiktError(f"{path}: the policy reads obs {obs_dim} and acts {act_dim}; environment '{env}' has "
                        f"obs {spec.obs_dim} / act {spec.act_dim}")
    check_registry_writable(registry, "teachers")
    fingerprint = spec_fingerprint(spec)
    carried, _ = env_to_carry(env, fingerprint, env=resolved)
    card = TeacherCard(
        name=teacher_name, version=1, env=env, env_spec=spec.model_dump(), env_fingerprint=fingerprint,
        obs_dim=obs_dim, act_dim=act_dim,
        pi_hidden=policy.pi.hidden_sizes, vf_hidden=policy.vf.hidden_sizes, activation=imported.activation,
        obs_clip=None if obs_stats is None else OBS_CLIP,  # without statistics it saw raw, unclipped observations
        clip_actions_for_env=True,  # SB3 and CleanRL's ppo_continuous_action clip actions for the env
        steps=0, seed=None, final_return=None, best_return=None, hyperparameters={},
        packages=package_versions(), code_version=code_version(), imported_from=imported.source,
        created=now(), tensors_sha256="",
    )
    policy.obs_normalizer.frozen = True
    return publish_teacher(registry, card, policy, carried)


def shadowed_teacher(registry: Path, card: TeacherCard) -> TeacherCard | None:
    """The version that `card` replaced as its name's latest, which references without a version (`hopper`,
    as grids write them) meant until now; None when the name was new."""
    older = [v for v in versions(registry, card.name) if v < card.version]
    if not older:
        return None
    return read_teacher_card(resolve(registry, f"{card.name}@v{older[-1]}"))  # either layer: a shipped one too
