"""Trains the shipped teachers with the paper's settings, one after another, resumably, through the library.

    python benchmarks/train_teachers.py            # all of them, in this order
    python benchmarks/train_teachers.py hopper     # just one

Each teacher is the library's `start_teacher` + `train_teacher` (what `mikt teacher train ENV --steps N --seed S`
runs); an interrupted run is resumed from its checkpoint, a finished one is skipped. Learning curves are
copied to benchmarks/results/teachers/v2/ (the teachers of mikt 0.2: raw actions, the paper's 2M budget;
v1's curves stay in benchmarks/results/teachers/). Progress goes to stderr.
"""

from __future__ import annotations

import os
import shlex
import shutil
import sys
from pathlib import Path

import torch

from miktcli.registry.cards import TeacherVersion
from miktcli.registry.runs import Run, list_runs
from miktcli.registry.teachers import load_teacher, versions
from miktcli.workflows.session import Phase, run_to_end
from miktcli.workflows.teacher import start_teacher, train_teacher

ROOT = Path(__file__).resolve().parents[1]
REGISTRY = Path(os.environ.get("MIKT_REGISTRY", ROOT / "registry"))
RESULTS = Path(os.environ.get("MIKT_RESULTS", ROOT / "benchmarks" / "results")) / "teachers" / "v2"
STEPS = 2_000_896  # the paper's 2M, as whole 2048-step rollouts (what `--steps 2000000` trains)
JOBS = [  # (env, steps, seed), in the order the paper-scale study needs them
    ("centipede-four", STEPS, 0),
    ("centipede-six", STEPS, 0),
    ("ant", STEPS, 0),
    ("hopper", STEPS, 0),
    # the two teachers the multi-teacher study adds (CAT's four + eight -> six, four + cp-six -> eight)
    ("centipede-eight", STEPS, 0),
    ("cp-centipede-six", STEPS, 0),
]


def find_run(env: str, steps: int, seed: int) -> Run | None:
    runs, _ = list_runs(REGISTRY)
    matches = [r for r in runs if (r.card.kind, r.card.env, r.card.total_steps, r.card.seed)
               == ("teacher", env, steps, seed)]
    return matches[-1] if matches else None


def published(env: str, steps: int, seed: int) -> str | None:
    """A committed teacher of `env` trained like this job (raw actions, these steps and seed): the job is
    done even where its run folder is not (a fresh clone holds registry/teachers, not registry/runs)."""
    for version in reversed(versions(REGISTRY, env)):
        card = load_teacher(REGISTRY, str(TeacherVersion(env, version))).card
        if (card.steps, card.seed, card.clip_actions_for_env) == (steps, seed, False):
            return card.ref
    return None


def report(label: str):
    def show(event) -> None:
        if isinstance(event, Phase):
            print(f"{label}: {event.name} {event.detail}", file=sys.stderr, flush=True)
        elif event["iteration"] % 50 == 0:
            print(f"{label}: {event['steps']:,} steps, return {event['return_mean']:.1f}, "
                  f"{event['steps_per_sec']:.0f} steps/s", file=sys.stderr, flush=True)
    return show


def main(selected: list[str]) -> None:
    torch.set_num_threads(1)
    for env, steps, seed in JOBS:
        if selected and env not in selected:
            continue
        run = find_run(env, steps, seed)
        if run is None and (ref := published(env, steps, seed)):
            print(f"{env}: done ({ref}, published; its run folder is not in this registry)", flush=True)
            continue
        if run is not None and run.card.status == "completed":
            print(f"{env}: done in {run.id} ({run.card.result.get('teacher')})", flush=True)
        else:
            if run is None:
                command = shlex.join(["python", "benchmarks/train_teachers.py", env])
                run = start_teacher(REGISTRY, env=env, steps=steps, seed=seed, command=command)
            print(f"{env}: training {run.id} from {run.card.steps_done:,} steps", flush=True)
            card = run_to_end(train_teacher(run, REGISTRY), report(run.id))
            print(f"{env}: published {card.ref} (final return {card.final_return:.1f})", flush=True)
        RESULTS.mkdir(parents=True, exist_ok=True)
        shutil.copy(run.metrics_path, RESULTS / f"{env}-metrics.jsonl")
        shutil.copy(run.path / "run.json", RESULTS / f"{env}-run.json")


if __name__ == "__main__":
    main(sys.argv[1:])
