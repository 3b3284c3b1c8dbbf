"""A method written the way a contributor would add one: this file, plus one line in METHODS (the tests add
it temporarily). PPO from scratch whose action noise starts at a chosen log-std: one option."""

from __future__ import annotations

import torch
from pydantic import BaseModel, ConfigDict, Field

from miktcli.engine.policies import GaussianActorCritic
from miktcli.methods.base import Method, keep_agent


class ToyConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    init_log_std: float = Field(0.0, le=1.0, description="log-std of the action noise at the start")


def build(obs_dim: int, act_dim: int, teachers: list[GaussianActorCritic],
          hidden: tuple[list[int], list[int]], options: BaseModel | None) -> GaussianActorCritic:
    assert isinstance(options, ToyConfig)
    agent = GaussianActorCritic(obs_dim, act_dim, *hidden)
    with torch.no_grad():
        agent.log_std.fill_(options.init_log_std)
    return agent


METHOD = Method(name="toy", summary="PPO from scratch, chosen initial noise", min_teachers=0, max_teachers=0,
                default_kl_coef=0.0, options=ToyConfig, build=build, student=keep_agent)
