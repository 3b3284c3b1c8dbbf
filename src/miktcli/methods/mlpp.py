"""MLPP (paper §4): the teacher's middle stack as initialisation; fresh input and output layers."""

from __future__ import annotations

import torch
from pydantic import BaseModel

from miktcli.engine.policies import GaussianActorCritic
from miktcli.methods.base import Method, keep_agent


def mlpp_from_teacher(teacher: GaussianActorCritic, obs_dim: int, act_dim: int) -> GaussianActorCritic:
    """Copy every hidden→hidden layer of the teacher's policy and value MLPs; all layers are then fine-tuned."""
    student = GaussianActorCritic(obs_dim, act_dim, teacher.pi.hidden_sizes, teacher.vf.hidden_sizes)
    with torch.no_grad():
        for net, source in ((student.pi, teacher.pi), (student.vf, teacher.vf)):
            for j in range(1, len(net.hidden)):  # layer 0 reads the observation: it stays fresh
                net.hidden[j].weight.copy_(source.hidden[j].weight)
                net.hidden[j].bias.copy_(source.hidden[j].bias)
    student.requires_grad_(True)
    return student


def build(obs_dim: int, act_dim: int, teachers: list[GaussianActorCritic],
          hidden: tuple[list[int], list[int]], options: BaseModel | None) -> GaussianActorCritic:
    return mlpp_from_teacher(teachers[0], obs_dim, act_dim)


METHOD = Method(name="mlpp", summary="the teacher's middle layers as initialisation, all fine-tuned",
                min_teachers=1, max_teachers=1, default_kl_coef=0.0, options=None, build=build, student=keep_agent,
                plain_actor_critic=True)
