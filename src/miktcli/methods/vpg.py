"""VPG (paper §4): PPO from scratch on the target, the same hyper-parameters; also how teachers are trained."""

from __future__ import annotations

from pydantic import BaseModel

from miktcli.engine.policies import GaussianActorCritic
from miktcli.methods.base import Method, keep_agent


def build(obs_dim: int, act_dim: int, teachers: list[GaussianActorCritic],
          hidden: tuple[list[int], list[int]], options: BaseModel | None) -> GaussianActorCritic:
    return GaussianActorCritic(obs_dim, act_dim, *hidden)


METHOD = Method(name="vpg", summary="PPO from scratch", min_teachers=0, max_teachers=0, default_kl_coef=0.0,
                options=None, build=build, student=keep_agent, plain_actor_critic=True)
# `mikt teacher train` runs are recorded as method "ppo": the same agent, not offered by `mikt transfer`.
TEACHER_PPO = Method(name="ppo", summary="PPO (teacher training)", min_teachers=0, max_teachers=0,
                     default_kl_coef=0.0, options=None, build=build, student=keep_agent, plain_actor_critic=True,
                     for_transfer=False)
