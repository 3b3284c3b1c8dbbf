"""Transfer methods: each is one module plus one line in METHODS.

A method turns an environment's dimensions, the frozen teacher policies and the student's hidden sizes into
the policy/value module the one PPO engine trains (an `ActorCritic`, which may add its own loss terms).
Methods depend only on nets, policies and envs; loading teachers and runs is the workflows' job.
"""

from __future__ import annotations

from miktcli.errors import MiktError
from miktcli.methods import mikt, mlpp, vpg
from miktcli.methods.base import Method

METHODS: dict[str, Method] = {m.name: m for m in (vpg.METHOD, vpg.TEACHER_PPO, mlpp.METHOD, mikt.METHOD)}


def get_method(name: str) -> Method:
    if name not in METHODS:
        known = ", ".join(n for n, m in METHODS.items() if m.for_transfer)
        raise MiktError(f"unknown method '{name}'; known: {known}")
    return METHODS[name]


def transfer_methods() -> list[str]:
    return [n for n, m in METHODS.items() if m.for_transfer]
