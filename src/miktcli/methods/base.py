"""The record every transfer method registers: what it is called, what it needs, how it builds its agent."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from pydantic import BaseModel

from miktcli.errors import MiktError
from miktcli.policies import ActorCritic, GaussianActorCritic

# build(obs_dim, act_dim, teacher policies, (pi_hidden, vf_hidden), options) -> the module PPO trains
Builder = Callable[[int, int, list[GaussianActorCritic], tuple[list[int], list[int]], BaseModel | None], ActorCritic]


def keep_agent(agent: ActorCritic) -> GaussianActorCritic:
    """The student of a method whose agent is already a plain actor-critic."""
    assert isinstance(agent, GaussianActorCritic)
    return agent


@dataclass(frozen=True)
class Method:
    name: str
    summary: str
    min_teachers: int
    max_teachers: int | None  # None: any number
    default_kl_coef: float
    options: type[BaseModel] | None  # the method's own options, recorded in the run card
    build: Builder
    student: Callable[[ActorCritic], GaussianActorCritic]  # the teacher-free policy saved at the end
    with_teachers: Callable[[ActorCritic], ActorCritic] | None = None  # the agent using its teachers, if any
    for_transfer: bool = True  # offered by `mikt transfer` (the teacher trainer's plain PPO is not)

    def parse_options(self, values: dict | None) -> BaseModel | None:
        if self.options is None:
            if values:  # options for another method (a grid's `mikt = {...}` under vpg): never silently dropped
                raise MiktError(f"method {self.name} takes no options; got {', '.join(sorted(values))}")
            return None
        return self.options.model_validate(values or {})

    @property
    def trains_from_scratch(self) -> bool:
        """Takes no teachers: a study runs it once per target and seed, shared by every pair."""
        return self.max_teachers == 0

    def check_teacher_count(self, n: int) -> None:
        if n < self.min_teachers:
            raise MiktError(f"method {self.name} needs a teacher")
        if self.max_teachers is not None and n > self.max_teachers:
            raise MiktError(f"method {self.name} trains from scratch: it takes no teachers" if self.trains_from_scratch
                            else f"method {self.name} takes at most {self.max_teachers} teacher(s), got {n}")

