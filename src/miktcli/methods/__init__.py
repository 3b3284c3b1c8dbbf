"""Builds the policy/value module a run trains, from its card: the one place methods are told apart."""

from __future__ import annotations

from pathlib import Path

from miktcli.envs import load_spec
from miktcli.errors import MiktError
from miktcli.policies import ActorCritic, GaussianActorCritic
from miktcli.registry.runs import Run

METHODS = ("ppo", "vpg", "mlpp", "mikt")


def build_agent(run: Run, registry: Path) -> ActorCritic:
    spec = load_spec(run.card.env)
    cfg = run.card.config
    if run.card.method in ("ppo", "vpg"):
        return GaussianActorCritic(spec.obs_dim, spec.act_dim, cfg["pi_hidden"], cfg["vf_hidden"])
    if run.card.method == "mlpp":
        from miktcli.methods.mlpp import build_mlpp

        return build_mlpp(run, registry, spec)
    if run.card.method == "mikt":
        from miktcli.methods.mikt import build_mikt

        return build_mikt(run, registry, spec)
    raise MiktError(f"run '{run.id}': unknown method '{run.card.method}'; known: {', '.join(METHODS)}")
