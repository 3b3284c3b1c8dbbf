"""A training session: creates runs, builds the agent and PPO trainer from the run card (through its method),
checkpoints every iteration, holds the run's lock, records how it ended, resumes exactly."""

from __future__ import annotations

import copy
import math
import shutil
import tempfile
from collections.abc import Callable, Generator, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import torch

from miktcli import limits
from miktcli.engine.episodes import evaluation_summary
from miktcli.engine.policies import TEACHER_FREE, ActorCritic
from miktcli.engine.ppo import PPOTrainer, complete_state, state_misfit
from miktcli.envs import make_env
from miktcli.envs.fingerprint import spec_fingerprint, spec_record
from miktcli.errors import MiktError
from miktcli.limits import check_count
from miktcli.methods import get_method
from miktcli.registry.cards import CodeSegment, RunConfig, TeacherRef, code_version, now, package_versions
from miktcli.registry.carried import NotCarried, ResolvedEnv, carry_into_run, resolve_new_env, resolve_run_env
from miktcli.registry.runs import Run, RunLock, create_run
from miktcli.registry.teachers import load_run_teachers
from miktcli.workflows.slowdown import SlowdownWatch, update_ratio

MAX_SEED = 2**32 - 1  # numpy's and torch's seeding range
EVAL_SEED_OFFSET = 10_000  # evaluation episodes never reuse training seeds


def whole_rollouts(steps: int, batch_size: int) -> int:
    """A budget rounded up to whole rollouts: a run never trains fewer steps than asked (the card says how
    many it trains; 2M steps → 977 rollouts of 2048 = 2,000,896)."""
    return -(-steps // batch_size) * batch_size


def check_registry_writable(registry: Path, *folders: str) -> None:
    """Fail before any training if the registry cannot take the files a run will write at its end."""
    for name in folders:
        folder = Path(registry) / name
        try:
            folder.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryFile(dir=folder):
                pass
        except OSError as err:
            raise MiktError(f"registry folder {folder} is not writable: {err.strerror or err}",
                            hint="check its permissions and free space, or choose another --registry") from err


def new_run(registry: Path, *, kind: str, env: str, method: str, seed: int, total_steps: int,
            config: RunConfig, command: str, teachers: list[TeacherRef] | None = None,
            resolved: ResolvedEnv | None = None) -> Run:
    """Validate everything a run needs, then create its folder, carrying its environment (registry/carried.py;
    `resolved`: where the caller found it, else the spec folders). Nothing is created when a check fails."""
    check_count("--steps", total_steps, limits.MAX_STEPS)
    check_count("--num-envs", config.ppo.num_envs, limits.MAX_NUM_ENVS)
    asked, total_steps = total_steps, whole_rollouts(total_steps, config.ppo.batch_size)
    limits.check_rounding(asked, total_steps, config.ppo.batch_size)
    if not 0 <= seed <= MAX_SEED:
        raise MiktError(f"--seed {seed} is out of range: 0 to {MAX_SEED}")
    get_method(method).parse_options(config.options)
    resolved = resolved or resolve_new_env(env)  # fail on an unknown env before a run folder exists
    spec = resolved.spec
    limits.check_model_size(spec.obs_dim, spec.act_dim, config.pi_hidden, config.vf_hidden)
    fingerprint = spec_fingerprint(spec)
    check_registry_writable(registry, "runs", *(["teachers"] if kind == "teacher" else []))
    run = create_run(
        registry, kind=kind, env=env, method=method, seed=seed, total_steps=total_steps, config=config,
        command=command, teachers=teachers or [], code_version=code_version(), packages=package_versions(),
        env_spec=spec_record(spec), env_fingerprint=fingerprint,
    )
    carry_env(run, resolved)
    return run


def carry_env(run: Run, resolved: ResolvedEnv) -> None:
    """Put a copy of the run's environment into its folder (runN/env/). A model that cannot travel
    (carried.NotCarried) leaves the run as runs were before; any other failure removes the new run."""
    try:
        carry_into_run(run.path, resolved, run.card.env_fingerprint)
    except NotCarried:
        pass
    except BaseException:
        shutil.rmtree(run.path, ignore_errors=True)
        raise


def run_env(run: Run, doing: str) -> ResolvedEnv:
    """The environment of a run, from the spec folders or the copy the run carries (registry/carried.py);
    refused when it differs from the one the run started on (a run recorded before mikt kept fingerprints is
    taken as it is)."""
    return resolve_run_env(run.path, run.id, run.card.env, run.card.env_fingerprint, doing)


@dataclass(frozen=True)
class Phase:
    """A progress event between iterations (e.g. the final evaluation starting)."""

    name: str
    detail: str = ""


Event = dict[str, Any] | Phase  # an iteration's metrics, or a phase
T = TypeVar("T")


def run_to_end(events: Generator[Event, None, T], on_event: Callable[[Event], None] | None = None) -> T:
    """Drive a workflow generator to its end, handing every progress event to `on_event`; its result."""
    while True:
        try:
            event = next(events)
        except StopIteration as stop:
            return stop.value
        if on_event is not None:
            on_event(event)


class Job:
    """A run's agent and trainer, restored from its last checkpoint when there is one.

    Use it as a context manager around everything from training to publishing: it holds the run's lock
    (so no second process can train or resume the same run) and, on leaving, records how the run ended:
    `interrupted` on Ctrl-C/SIGTERM, `failed` with the reason on any other exception."""

    def __init__(self, run: Run, registry: Path):
        self.run, self.registry = run, registry
        self.lock = RunLock(run).acquire()
        try:
            torch.manual_seed(run.card.seed)
            self.env = run_env(run, "cannot train")
            self.spec = self.env.spec
            self.method = get_method(run.card.method)
            self.agent = build_agent(run, registry, self.spec)
            self.config = run.card.config.ppo
            self.trainer = PPOTrainer(self.agent, lambda: make_env(self.spec), self.config, run.card.total_steps,
                                      seed=run.card.seed)
            self.best_return = -math.inf
            self.eval_episodes = run.card.config.eval_episodes or 10  # cards before schema 3: the CLI default
            if run.checkpoint_path.exists():
                ckpt, tensors = run.load_checkpoint()
                try:
                    self.trainer.load_state(tensors, ckpt.progress)
                except ValueError as err:
                    raise MiktError(f"{run.checkpoint_path}: {err}",
                                    hint="the checkpoint is damaged or from another run") from err
                self.best_return = ckpt.progress.get("best_return", -math.inf)
                run.truncate_metrics(ckpt.iteration)
            self.slowdowns = SlowdownWatch([(self._phase_of(r["iteration"]), r["steps"], update_ratio(r))
                                            for r in run.read_metrics()])
        except BaseException as err:
            self._record_end(err)
            self.lock.release()
            raise

    def __enter__(self) -> Job:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self._record_end(exc)
        self.close()

    def _record_end(self, exc: BaseException | None) -> None:
        if exc is None:
            return
        if isinstance(exc, KeyboardInterrupt):
            self.run.save_card(status="interrupted")
        else:
            self.run.save_card(status="failed", error=f"{type(exc).__name__}: {exc}")

    def close(self) -> None:
        trainer = getattr(self, "trainer", None)
        if trainer is not None:
            trainer.close()
        self.lock.release()

    def iterations(self) -> Iterator[dict[str, Any] | Phase]:
        """Train to the end, checkpointing after every iteration (and keeping one at each change of phase)."""
        yield from self.begin()
        for metrics in self.trainer.run():
            yield from self.record(metrics)

    def begin(self) -> Iterator[Phase]:
        """Mark the run running in this process's code (before its first iteration here)."""
        run, trainer = self.run, self.trainer
        run.save_card(status="running", error=None,
                      code_history=continued_code_history(run.card.code_history, trainer.global_step))
        if self.env.note:  # trained from the copy the run carries: say so, and where it lies
            yield Phase("environment", self.env.detail)
        yield from self._phase_change()

    def record(self, metrics: dict[str, Any]) -> Iterator[dict[str, Any] | Phase]:
        """Keep an iteration the trainer finished: checkpoint, metrics row, card; then any change of phase."""
        run, trainer = self.run, self.trainer
        if math.isfinite(metrics["return_mean"]):
            self.best_return = max(self.best_return, metrics["return_mean"])
        progress = {**trainer.progress_state(), "best_return": self.best_return}
        # Checkpoint first: a metrics row never describes an iteration the checkpoint lacks.
        run.save_checkpoint(trainer.state_tensors(), trainer.iteration, trainer.global_step, progress)
        run.append_metrics(metrics)
        slowed = self.slowdowns.add(self._phase_of(trainer.iteration), trainer.global_step, update_ratio(metrics))
        if slowed is not None:  # kept in the card, so `inspect` and study reports say so
            run.save_card(result={**run.card.result, "slowdowns": [*run.card.result.get("slowdowns", []), slowed]})
        run.save_card(steps_done=trainer.global_step)
        yield metrics
        yield from self._phase_change()

    def _phase_of(self, iteration: int) -> str:
        """The schedule's phase during an iteration (1-based, as metrics rows count them)."""
        return self.agent.phase((iteration - 1) / self.trainer.num_iterations)

    def _phase_change(self) -> Iterator[Phase]:
        """Between two iterations where the schedule changes phase: keep the checkpoint as
        `checkpoint-before-PHASE` (to branch from it later), and at the hand-over to the teacher-free student
        evaluate both sides of it on that same checkpoint."""
        trainer, agent, run = self.trainer, self.agent, self.run
        if not 0 < trainer.iteration < trainer.num_iterations:
            return
        last, upcoming = trainer.iteration - 1, trainer.iteration
        before, after = (agent.phase(i / trainer.num_iterations) for i in (last, upcoming))
        if before == after:
            return
        run.keep_checkpoint(f"before-{after}")
        if after == TEACHER_FREE and self.method.with_teachers is not None:
            yield Phase("hand-over", f"evaluating with and without the teachers, {self.eval_episodes} episodes")
            run.save_card(result={**run.card.result, "handover": self._evaluate_handover(upcoming)})

    def _evaluate_handover(self, upcoming: int) -> dict[str, Any]:
        """The deterministic return of the mixed policy just before the drop and of the teacher-free student
        right after the hand-over, from the same weights and on the same evaluation episodes."""
        trainer = self.trainer
        record = evaluate_handover(self.agent, self.method, self.env.name, self.eval_episodes,
                                   EVAL_SEED_OFFSET + self.run.card.seed, self.config.clip_actions_for_env,
                                   upcoming / trainer.num_iterations)
        return {"at_step": trainer.global_step, **record}

    @property
    def final_return(self) -> float | None:
        returns = self.trainer.recent_returns
        return float(sum(returns) / len(returns)) if returns else None


def evaluate_handover(agent: ActorCritic, method, env_name: str, episodes: int, seed: int, clip: bool,
                      upcoming_fraction: float) -> dict[str, Any]:
    """Both sides of the drop on `agent` as it is just before it: the mixed policy's deterministic return, then
    the hand-over itself (`agent` moved on to `upcoming_fraction`, what the next iteration's schedule step
    does, so a fold changes its weights) and the teacher-free student's, on the same `episodes` from `seed`.
    torch's global generator is put back: training's own generators are untouched."""
    rng = torch.random.get_rng_state()
    try:
        with torch.no_grad():
            mixed = evaluation_summary(copy.deepcopy(agent), env_name, episodes, seed, clip)
            agent.set_progress(upcoming_fraction)
            alone = evaluation_summary(method.student(agent), env_name, episodes, seed, clip)
    finally:
        torch.random.set_rng_state(rng)
    kept = alone["return_mean"] / mixed["return_mean"] if mixed["return_mean"] > 0 else None
    record = {"with_teachers": mixed, "without_teachers": alone, "kept_fraction": kept}
    details = agent.handover_details()
    return {**record, "fit": details} if details else record


def continued_code_history(history: list[CodeSegment], step: int) -> list[CodeSegment]:
    """The history with this process's code training from `step` on: a new segment only when the code or the
    packages differ from the last segment's (a study's chunks and plain resumes add nothing). A last segment
    that trained nothing (stopped before its first checkpoint) is replaced, not followed."""
    current = CodeSegment(from_step=step, code_version=code_version(), packages=package_versions(), started=now())
    if history and (history[-1].code_version, history[-1].packages) == (current.code_version, current.packages):
        return history
    if history and history[-1].from_step == step:
        history = history[:-1]
    return [*history, current]


def build_agent(run: Run, registry: Path, spec) -> ActorCritic:
    """The module a run trains on `spec` (its environment, from `run_env`), built by its method from the run
    card (and the exact teachers it names)."""
    method = get_method(run.card.method)
    teachers = [t.policy for t in load_run_teachers(run, registry)]
    cfg = run.card.config
    return method.build(spec.obs_dim, spec.act_dim, teachers, (cfg.pi_hidden, cfg.vf_hidden),
                        method.parse_options(cfg.options))


def agent_from_checkpoint(run: Run, registry: Path, spec, path: Path | None = None) -> ActorCritic:
    """A run's agent on `spec` with the weights of its last checkpoint, or of the one at `path` (a kept
    checkpoint), for evaluation, not for training."""
    return agent_at_checkpoint(run, registry, spec, path)[0]


def agent_at_checkpoint(run: Run, registry: Path, spec, path: Path | None = None) -> tuple[ActorCritic, Any]:
    """agent_from_checkpoint, and the checkpoint's card (its iteration and steps)."""
    agent = build_agent(run, registry, spec)
    ckpt, tensors = run.load_checkpoint(path)
    state = {k[len("agent."):]: v for k, v in tensors.items() if k.startswith("agent.")}
    problem = state_misfit(agent, state)
    if problem:
        raise MiktError(f"{path or run.checkpoint_path}: {problem}")
    agent.load_state_dict(complete_state(agent, state))
    return agent, ckpt
