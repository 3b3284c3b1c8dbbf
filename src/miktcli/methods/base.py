"""The record every transfer method registers: what it is called, what it needs, how it builds its agent."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from pydantic import BaseModel, ValidationError

from miktcli.engine.policies import ActorCritic, GaussianActorCritic
from miktcli.errors import MethodOptionError, TeacherCountError, describe_validation_error

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
    # The method's own options: the one source of their names, defaults, choices and help. `mikt transfer`
    # takes each field as a flag (--field-name VALUE, --field/--no-field for a bool), a grid under
    # `options = {...}`, and every run card records the validated model.
    options: type[BaseModel] | None
    build: Builder
    student: Callable[[ActorCritic], GaussianActorCritic]  # the teacher-free policy saved at the end
    with_teachers: Callable[[ActorCritic], ActorCritic] | None = None  # the agent using its teachers, if any
    for_transfer: bool = True  # offered by `mikt transfer` (the teacher trainer's plain PPO is not)
    # Maps the target observation to each teacher's state dimension (an encoder per teacher), so a stated
    # encoder width is checked against the teacher's card.
    encoder_per_teacher: bool = False
    # Its agent is the plain Gaussian actor-critic, every parameter trained: its update can have its gradient
    # by hand (engine/by_hand.py), which new runs then do unless told otherwise (PPOConfig.gradients).
    plain_actor_critic: bool = False

    def parse_options(self, values: dict | None) -> BaseModel | None:
        if self.options is None:
            if values:  # options for another method (a grid's `options = {...}` under vpg): never silently dropped
                raise MethodOptionError(f"method {self.name} takes no options; got {', '.join(sorted(values))}",
                                        method=self.name, option=sorted(values)[0])
            return None
        try:
            return self.options.model_validate(values or {})
        except ValidationError as err:
            loc = err.errors()[0]["loc"]
            raise MethodOptionError(f"bad {self.name} option: {describe_validation_error(err)}", method=self.name,
                                    option=loc[0] if loc and isinstance(loc[0], str) else None) from err

    @property
    def mixes_teachers(self) -> bool:
        """Its agent mixes the teachers in with learned weights (logged as p_* metrics)."""
        return self.with_teachers is not None

    @property
    def trains_from_scratch(self) -> bool:
        """Takes no teachers: a study runs it once per target and seed, shared by every pair."""
        return self.max_teachers == 0

    def check_teacher_count(self, n: int) -> None:
        counts = {"given": n, "minimum": self.min_teachers, "maximum": self.max_teachers}
        if n < self.min_teachers:
            raise TeacherCountError(f"method {self.name} needs a teacher", **counts)
        if self.max_teachers is not None and n > self.max_teachers:
            raise TeacherCountError(f"method {self.name} trains from scratch: it takes no teachers"
                                    if self.trains_from_scratch
                                    else f"method {self.name} takes at most {self.max_teachers} teacher(s), got {n}",
                                    **counts)

