"""Whether a run's update goes through torch.compile (PPOConfig.compile_loss): asked, or decided from its size.

`--compile` / `--no-compile` decide; without either ("auto") a run compiles when it is long enough to repay
the compile and a C++ compiler is there. Measured (the project's throughput benchmark, Ant PPO and centipede-eight
MIKT, 1 env): the compiled minibatch step saves ~0.4 ms (PPO) to ~1.5 ms (MIKT) of ~1.1 / ~3.9 ms, i.e.
0.13-0.5 s per 2,048-step iteration, against ~20-30 s of compiling per graph (one for PPO, one per phase of
MIKT's three-phase schedule). PPO repays it at ~500k steps, MIKT earlier, so auto compiles from 500k steps:
every paper-scale (2M) run, none of the tests' or a quick try's. The decision and its reason go into the
run card (PPOConfig.compile_reason): the compiled update is the same maths to float rounding, never a
silent change.
"""

from __future__ import annotations

import functools
import os
import shutil
import subprocess

from miktcli.errors import MiktError

AUTO_MIN_STEPS = 500_000


def cxx_compiler() -> str | None:
    """The C++ compiler torch.compile's CPU backend would use ($CXX, else g++, c++ or clang++), or None."""
    for name in (os.environ.get("CXX"), "g++", "c++", "clang++"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


@functools.cache
def compiler_works(cxx: str) -> bool:
    """Whether `cxx` compiles a one-line C++ program (a compiler that is there but broken, e.g. CXX=/bin/false,
    would otherwise fail the run at its first update)."""
    try:
        done = subprocess.run([cxx, "-x", "c++", "-fsyntax-only", "-"], input="int main() { return 0; }\n",
                              capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.SubprocessError):
        return False
    return done.returncode == 0


def change_on_resume(recorded: str, compiled: bool, step: int) -> str:
    """The card's compile_reason once a resume asked for the other update mode: both, with the step."""
    return f"{recorded}; from step {step:,}: {'on' if compiled else 'off'}, asked on resume " \
           f"({'--compile' if compiled else '--no-compile'})"


def decide_gradients(asked: str | None, plain_actor_critic: bool, together: bool,
                     compile_asked: bool | None = None) -> str:
    """PPOConfig.gradients for a new run: as asked (`--ppo gradients=…`, a grid's ppo); else autograd where
    --compile or --no-compile chose one of autograd's paths; else by hand wherever it can be (engine/by_hand.py:
    the plain actor-critic of PPO, VPG and MLPP, one seed at a time), else autograd. A by-hand request it
    cannot take is refused here, before any run folder is made."""
    if asked == "by-hand" and not plain_actor_critic:
        raise MiktError("gradients=by-hand: only the plain actor-critic (teacher training, vpg, mlpp) has its "
                        "gradient by hand; a transfer method with teachers needs gradients=autograd")
    if asked == "by-hand" and together:
        raise MiktError("gradients=by-hand trains one seed at a time; seeds together (--seeds, a grid's "
                        "seeds_together) needs gradients=autograd")
    if asked is not None:
        return asked
    if compile_asked is not None:
        return "autograd"
    return "by-hand" if plain_actor_critic and not together else "autograd"


def decide_compile(requested: bool | None, total_steps: int, by_hand: bool = False) -> tuple[bool, str]:
    """(compile or not, the reason recorded in the card). requested: True/False asked, None for auto.
    by_hand: the run's gradient is by hand (PPOConfig.gradients), so there is no loss to compile."""
    if by_hand:
        if requested is True:
            raise MiktError("--compile: a run with gradients=by-hand computes no loss to compile; drop --compile, "
                            "or set --ppo gradients=autograd")
        return False, "off: the gradient is by hand (gradients=by-hand), nothing to compile"
    if requested is True:
        return True, "on: asked (--compile)"
    if requested is False:
        return False, "off: asked (--no-compile)"
    if total_steps < AUTO_MIN_STEPS:
        return False, (f"auto: off, {total_steps:,} steps is below {AUTO_MIN_STEPS:,}, where the compile "
                       f"(~20-30 s per graph) is repaid")
    cxx = cxx_compiler()
    if cxx is None:
        return False, "auto: off, no C++ compiler found (torch.compile needs one: install g++, or set $CXX)"
    if not compiler_works(cxx):
        return False, f"auto: off, the C++ compiler {cxx} does not compile a test program"
    return True, f"auto: on, {total_steps:,} steps (compiling pays from {AUTO_MIN_STEPS:,})"
