"""Branching: a new transfer run that starts from a checkpoint another run kept (`checkpoint-before-PHASE`),
with some of the method's options changed. What it is for: trying several hand-overs (or any option that
acts after that point) on the *same* weights, so that their difference is the option's and not the seed's."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from miktcli.engine.ppo import state_misfit
from miktcli.errors import MiktError
from miktcli.methods import get_method
from miktcli.registry.cards import BranchPoint, code_version, package_versions
from miktcli.registry.runs import Run, create_run, open_run
from miktcli.registry.teachers import load_run_teachers
from miktcli.workflows.session import carry_env, run_env


def branch_run(registry: Path, source_id: str, at: str, options: dict[str, Any], command: str) -> Run:
    """Check everything, then create the branch: its card (the source's settings with `options` changed, and
    where it branched from), the source's metrics up to that point, and the kept checkpoint as its own. The
    new run is left interrupted at that step: training it is resuming it."""
    source = open_run(registry, source_id)
    if source.card.kind != "transfer":
        raise MiktError(f"run '{source.id}' is a {source.card.kind} run; only transfers can be branched")
    kept = source.kept_checkpoints()
    if at not in kept:
        raise MiktError(f"run '{source.id}' kept no checkpoint '{at}'" +
                        (f"; it kept: {', '.join(kept)}" if kept else "; it kept none (runs before mikt kept "
                         "checkpoints at each phase, or a method without phases)"))
    ckpt, tensors = source.load_checkpoint(source.kept_checkpoint_path(at))
    method = get_method(source.card.method)
    parsed = method.parse_options({**(source.card.config.options or {}), **options})
    config = source.card.config.model_copy(update={"options": None if parsed is None else parsed.model_dump()})
    env = run_env(source, "cannot branch")
    spec = env.spec
    teachers = [t.policy for t in load_run_teachers(source, registry)]
    agent = method.build(spec.obs_dim, spec.act_dim, teachers, (config.pi_hidden, config.vf_hidden), parsed)
    state = {k[len("agent."):]: v for k, v in tensors.items() if k.startswith("agent.")}
    problem = state_misfit(agent, state)
    if problem:  # e.g. an option that changes the model's shape (lateral, mixing)
        raise MiktError(f"the changed options do not fit {source.id}'s checkpoint '{at}': {problem}",
                        hint="a branch may change options that act from its step on, not the model's shape")

    run = create_run(registry, kind="transfer", env=source.card.env, method=source.card.method,
                     seed=source.card.seed, total_steps=source.card.total_steps, config=config, command=command,
                     teachers=source.card.teachers, code_version=code_version(), packages=package_versions(),
                     env_spec=source.card.env_spec, env_fingerprint=source.card.env_fingerprint)
    if source.card.env_fingerprint is not None:
        carry_env(run, env)  # the source's copy where it has one: the branch trains on the same body
    # A hand-over recorded after the branch point belongs to the source's own continuation, not to this run.
    result = {k: v for k, v in source.card.result.items()
              if k == "handover" and isinstance(v, dict) and v.get("at_step", ckpt.steps) < ckpt.steps}
    run.save_card(status="interrupted", steps_done=ckpt.steps, result=result,
                  branched_from=BranchPoint(run=source.id, checkpoint=at, step=ckpt.steps),
                  code_history=[s for s in source.card.code_history if s.from_step < ckpt.steps])
    run.write_metrics([r for r in source.read_metrics() if r["iteration"] <= ckpt.iteration])
    run.save_checkpoint(tensors, ckpt.iteration, ckpt.steps, ckpt.progress)
    return run
