"""A study's cells on Ray: in parallel on one machine (`--workers N`) or on a cluster (`--address`).

No shared filesystem is assumed. The driver's registry is the source of truth and `state.json` has one writer
(the driver). Each cell trains in *chunks*: a Ray task (1 CPU, one torch thread) receives the cell's run folder
and the teacher files it needs (as bytes, verified by sha256 on arrival), trains a few iterations in a
temporary registry, and hands the whole run folder back; the driver writes it atomically and sends the next
chunk. A chunk that dies with its worker or node is sent again from the last folder handed back, so a lost
worker costs at most one chunk. Resume is exact (checkpoints hold the envs' state), so a cell trained in chunks
on Ray has the same metrics as one trained in one go.

Ray is an optional extra: `pip install 'mikt[ray]'`.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import socket
import tempfile
import threading
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import Any

import torch

from miktcli.envs.spec import user_specs_dir
from miktcli.errors import MiktError
from miktcli.registry.files import deferred_interrupt, write_bytes_atomic
from miktcli.registry.runs import Run, RunLock, open_run
from miktcli.registry.teachers import resolve
from miktcli.studies.executor import CellEvent, Progress, training_units
from miktcli.studies.grid import Grid
from miktcli.studies.study import Study
from miktcli.workflows.session import run_to_end
from miktcli.workflows.together import train_transfers_together
from miktcli.workflows.transfer import train_transfer_chunk

CHUNK_ITERATIONS = 20  # iterations per task: ~40k steps, about a minute here; a lost worker costs at most this
MAX_ATTEMPTS = 3  # tries of one chunk when workers die under it
WAIT_S = 1.0  # the longest the driver waits for a chunk before it looks again (a stop, the progress)
# Tests only: "RUN:CHUNK:MARKER" in the driver's environment makes the first try of that run's CHUNK-th chunk
# (counted from 0 in this driver session) kill its worker outright, to prove the cell is sent again.
FAULT_ENV = "MIKT_RAY_FAULT"
ENV_FORWARD = ("MUJOCO_GL", "PYOPENGL_PLATFORM", "MIKT_ENVSPECS")
# How long `--address` may take to accept a connection. Ray itself retries a dead address for minutes,
# printing its log lines, so the address is tried first, before any cell is prepared.
RAY_CONNECT_TIMEOUT_S = 10.0


def ray_available() -> bool:
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


def require_ray():
    try:
        import ray
    except ImportError:
        raise MiktError("studies on Ray need the ray extra", hint="pip install 'mikt[ray]'") from None
    return ray


# --- the task (runs on a worker) ------------------------------------------------------------------------

def _folder_files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file() and p.name != "lock"}


def _maybe_fail_for_test(run_id: str, chunk: int, spec: str | None) -> None:
    if spec and spec.count(":") == 2:
        fault_run, fault_chunk, marker = spec.split(":")
        if fault_run == run_id and int(fault_chunk) == chunk and not Path(marker).exists():
            Path(marker).write_text("killed")
            os._exit(1)  # the worker process dies as if killed: no exception, no cleanup


def train_chunk_task(run_ids: list[str], run_files: dict[str, dict[str, bytes]],
                     teacher_files: dict[str, tuple[bytes, str]], chunk: int, iterations: int, eval_episodes: int,
                     fault: str | None = None) -> dict[str, dict[str, bytes]]:
    """Train one chunk of a cell (one run), or of a cell's seeds together, in a private temporary registry;
    return each run folder's files."""
    torch.set_num_threads(1)
    for run_id in run_ids:
        _maybe_fail_for_test(run_id, chunk, fault)
    with tempfile.TemporaryDirectory(prefix="mikt-cell-") as tmp:
        registry = Path(tmp)
        for relative, (data, sha) in teacher_files.items():
            if hashlib.sha256(data).hexdigest() != sha:
                raise MiktError(f"teacher file {relative} arrived damaged (sha256 mismatch)")
            write_bytes_atomic(registry / "teachers" / relative, data)
        for run_id in run_ids:
            for name, data in run_files[run_id].items():
                write_bytes_atomic(registry / "runs" / run_id / name, data)
        runs = [open_run(registry, run_id) for run_id in run_ids]
        if len(runs) == 1:
            run_to_end(train_transfer_chunk(runs[0], registry, eval_episodes, max_iterations=iterations))
        else:
            run_to_end(train_transfers_together(runs, registry, eval_episodes, max_iterations=iterations))
        return {run.id: _folder_files(run.path) for run in runs}


# --- the driver -----------------------------------------------------------------------------------------

@contextmanager
def stop_requests() -> Iterator[threading.Event]:
    """While the block runs, Ctrl-C and SIGTERM only set the event; the driver loop stops between two waits.

    A KeyboardInterrupt raised wherever the signal happens to land could land inside Ray's own calls (a
    task's submission and the pickling of its arguments, `ray.wait`), which may swallow or wrap it: a SIGTERM
    once ended a study with exit 1, a Ray stack trace and no word on how to resume. Taking the signal over
    for the loop also overrides any SIGTERM handler Ray installed meanwhile. A second signal stops at once.
    Only Python handlers that are not Ray's are taken over: where the caller had none, Ray's (which tears
    down Ray's processes and exits) stays in charge, as before."""
    stop = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return

    def request_stop(signum, frame) -> None:
        if signal.getsignal(signal.SIGALRM) in (signal.SIG_DFL, None):
            # Ray's core worker can hold SIGTERM at the C level (abseil's failure handler: a stack trace, then
            # on to this handler) and arms a 3 s alarm that aborts the process, mid-way through the clean
            # stop. No Python code here set an alarm, so the pending one is that.
            signal.alarm(0)
        if stop.is_set():
            raise KeyboardInterrupt
        stop.set()

    previous = {}
    for s in (signal.SIGINT, signal.SIGTERM):
        handler = signal.getsignal(s)
        if callable(handler) and not getattr(handler, "__module__", "").startswith("ray"):
            previous[s] = signal.signal(s, request_stop)
    try:
        yield stop
    finally:
        second_signal = False
        for s, handler in previous.items():
            try:
                signal.signal(s, handler)
            except KeyboardInterrupt:  # a pending second signal ran request_stop first; give the handler back
                second_signal = True
                signal.signal(s, handler)
        if second_signal:
            raise KeyboardInterrupt


def _teacher_payload(registry: Path, runs: list[Run]) -> dict[str, tuple[bytes, str]]:
    payload = {}
    for run in runs:
        for ref in run.card.teachers:
            path = resolve(registry, ref.ref)
            relative = f"{ref.name}/{path.name}"
            if relative not in payload:  # a cell's seeds share their teachers: each file sent once
                data = path.read_bytes()
                payload[relative] = (data, hashlib.sha256(data).hexdigest())
    return payload


def _write_back(run: Run, files: dict[str, bytes]) -> None:
    """The worker's run folder, written atomically file by file; run.json last so it never describes more
    than the checkpoint and metrics beside it."""
    for name in sorted(files, key=lambda n: n == "run.json"):
        if "/" in name or name.startswith("."):
            raise MiktError(f"worker returned an unexpected file name {name!r} for {run.id}")
        write_bytes_atomic(run.path / name, files[name])


def _update_progress(progress: CellEvent, files: dict[str, bytes]) -> str:
    card = json.loads(files["run.json"])
    progress.steps = card["steps_done"]
    lines = [ln for ln in files.get("metrics.jsonl", b"").decode().splitlines() if ln.strip()]
    if lines:
        last = json.loads(lines[-1])
        progress.return_mean, progress.steps_per_sec = last.get("return_mean"), last.get("steps_per_sec")
    return card["status"]


def _restore_sigterm(handler: Any) -> None:
    """ray.init installs its own SIGTERM handler (sys.exit; a local node's also kills Ray's processes), which
    bypassed the clean stop: cells were left `running` (then `stale`) and no message said how to resume. A
    Python handler the caller had (the CLI's raises KeyboardInterrupt, like Ctrl-C) goes back, so SIGTERM
    cancels the tasks, marks the cells interrupted and, when this process started Ray, shuts it down in the
    executor's own `finally`. With no Python handler before, Ray's stays: it is what cleans up Ray's processes."""
    if callable(handler) and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, handler)


def _host_port(address: str) -> tuple[str, int]:
    """The host and port of `auto` (the cluster `ray start` recorded on this machine) or HOST:PORT."""
    shown = address
    if address == "auto":
        from ray._private.services import canonicalize_bootstrap_address_or_die

        try:
            address = canonicalize_bootstrap_address_or_die("auto")
        except (ConnectionError, ValueError) as err:
            reason = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            raise MiktError(f"no Ray cluster answers at auto: {reason}",
                            hint="start one with `ray start --head`, or pass its HOST:PORT") from None
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536 or any(c.isspace() for c in host):
        raise MiktError(f"--address {shown!r}: expected auto or HOST:PORT (e.g. 10.0.0.5:6379)")
    return host.strip("[]"), int(port)


def check_address(address: str) -> None:
    """A cluster must accept a connection at `address` within RAY_CONNECT_TIMEOUT_S; else one line."""
    host, port = _host_port(address)
    try:
        socket.create_connection((host, port), timeout=RAY_CONNECT_TIMEOUT_S).close()
    except TimeoutError:
        reason = f"no answer within {RAY_CONNECT_TIMEOUT_S:g} s"
    except OSError as err:
        reason = err.strerror or type(err).__name__
    else:
        return
    where = address if address == f"{host}:{port}" else f"{address} ({host}:{port})"
    raise MiktError(f"no Ray cluster answers at {where}: {reason}",
                    hint="start one with `ray start --head`, then pass --address auto (or its HOST:PORT)")


def _connect(ray, workers: int | None, address: str | None, env_vars: dict[str, str]) -> None:
    """Join the cluster at `address`, or start a local instance with `workers` CPUs."""
    if address is not None:
        check_address(address)
    sigterm_before = signal.getsignal(signal.SIGTERM)
    try:
        if address is not None:
            ray.init(address=address, runtime_env={"env_vars": env_vars}, logging_level="ERROR",
                     log_to_driver=False)
        else:
            # Ray starts its workers at niceness 15; here they *are* the work, so they compete as equals.
            os.environ.setdefault("RAY_worker_niceness", "0")
            ray.init(num_cpus=workers, include_dashboard=False, runtime_env={"env_vars": env_vars},
                     logging_level="ERROR", log_to_driver=False)
    except Exception as err:  # noqa: BLE001 - connection and start-up failures come in many types
        raise MiktError(f"could not start or reach Ray ({address or 'local'}): {type(err).__name__}: {err}",
                        hint="for a cluster, start it with `ray start --head` and pass --address auto") from None
    finally:
        _restore_sigterm(sigterm_before)


@contextmanager
def ray_session(workers: int | None, address: str | None) -> Iterator[Any]:
    """Ray, connected for the block: the cluster at `address`, or a local instance with `workers` CPUs that
    is stopped at the end. Inside another session (or with Ray already initialised) it is that one."""
    ray = require_ray()
    if ray.is_initialized():
        yield ray
        return
    env_vars = {k: os.environ[k] for k in ENV_FORWARD if k in os.environ}
    if user_specs_dir().is_dir():  # ./envspecs is relative to the driver's folder, not a worker's
        env_vars["MIKT_ENVSPECS"] = str(user_specs_dir().resolve())
    env_vars.update({"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "MIKT_THREADS": "1"})
    _connect(ray, workers, address, env_vars)
    try:
        yield ray
    finally:
        if address is None and ray.is_initialized():
            ray.shutdown()


class RayDriver:
    """Sends the cells' chunks to Ray, at most one per CPU of the cluster, and takes back what returns: a
    chunk's files are written back and the cell's next chunk sent; a chunk whose worker died is sent again
    (up to MAX_ATTEMPTS tries); a cell whose chunk raised, or whose workers kept dying, fails alone. The
    driver holds every cell's lock from the start, so no local process trains them meanwhile.

    What one task trains is a *unit*: one cell, or with the grid's `seeds_together` a cell's unfinished
    seeds (studies.executor.training_units), which go and come back together and end together."""

    def __init__(self, ray, registry: Path, units: list[list[tuple[str, Run]]], *, capacity: int,
                 eval_episodes: int, chunk_iterations: int):
        self.ray, self.registry = ray, registry
        self.eval_episodes, self.chunk_iterations, self.capacity = eval_episodes, chunk_iterations, capacity
        self.task = ray.remote(num_cpus=1, max_retries=0)(train_chunk_task)
        self.system_errors = tuple(getattr(ray.exceptions, name) for name in (
            "WorkerCrashedError", "NodeDiedError", "ObjectLostError", "RaySystemError", "OwnerDiedError",
            "LocalRayletDiedError") if hasattr(ray.exceptions, name))
        # a unit is named by its first run's id; its runs train, fail and end together
        self.units = {unit[0][1].id: [run.id for _, run in unit] for unit in units if unit}
        self.progress = {run.id: CellEvent(key, run.id, run.card.total_steps, steps=run.card.steps_done)
                         for unit in units for key, run in unit}
        self.runs = {run.id: run for unit in units for _, run in unit}
        self.chunks = {unit_id: 0 for unit_id in self.units}  # chunks handed back, per unit, in this session
        self.locks: dict[str, RunLock] = {}
        self.in_flight: dict[Any, str] = {}  # task reference → unit id
        self.queue = list(self.units)

    def lock_all(self) -> None:
        for run_id, run in self.runs.items():
            self.locks[run_id] = RunLock(run).acquire()

    def _submit(self, unit_id: str) -> None:
        run_ids = self.units[unit_id]
        for run_id in run_ids:
            run = open_run(self.registry, run_id)
            if run.card.status != "running":  # in flight from now on (`mikt runs` in the meantime says so)
                run.save_card(status="running")
            self.runs[run_id] = run
        runs = [self.runs[run_id] for run_id in run_ids]
        ref = self.task.remote(run_ids, {run.id: _folder_files(run.path) for run in runs},
                               _teacher_payload(self.registry, runs), self.chunks[unit_id], self.chunk_iterations,
                               self.eval_episodes, os.environ.get(FAULT_ENV))
        self.in_flight[ref] = unit_id
        for run_id in run_ids:
            p = self.progress[run_id]
            p.attempts += 1
            if p.state == "queued":
                p.state = "training"

    def _end(self, unit_id: str, state: str, error: str | None = None) -> list[CellEvent]:
        ended = []
        for run_id in self.units[unit_id]:
            p = self.progress[run_id]
            p.state, p.error = state, error
            if state == "failed":
                self.runs[run_id].save_card(status="failed", error=error)
            self.locks.pop(run_id).release()
            ended.append(p)
        return ended

    def _take_back(self, ref, submit_next: bool = True) -> list[CellEvent]:
        """What a finished task means for its unit: the progress of its cells when they ended, else []. With
        submit_next False (the study is stopping) the unit's next chunk, or a retry, is not sent."""
        unit_id = self.in_flight.pop(ref)
        run_ids = self.units[unit_id]
        first = self.progress[run_ids[0]]
        try:
            files = self.ray.get(ref)
        except self.system_errors as err:
            if first.attempts < MAX_ATTEMPTS:
                for run_id in run_ids:
                    self.progress[run_id].state = "retrying"  # again from the last folders handed back
                if submit_next:
                    self._submit(unit_id)
                return []
            return self._end(unit_id, "failed", f"workers died {MAX_ATTEMPTS} times under one chunk: {err}")
        except self.ray.exceptions.RayTaskError as err:
            cause = err.cause if isinstance(getattr(err, "cause", None), BaseException) else err
            return self._end(unit_id, "failed", f"{type(cause).__name__}: {cause}")
        statuses = []
        for run_id in run_ids:
            _write_back(self.runs[run_id], files[run_id])
            statuses.append(_update_progress(self.progress[run_id], files[run_id]))
            self.progress[run_id].attempts = 0
        self.chunks[unit_id] += 1
        if all(status == "completed" for status in statuses):
            return self._end(unit_id, "completed")
        for run_id in run_ids:
            self.progress[run_id].state = "training"
        if submit_next:
            self._submit(unit_id)
        return []

    def run(self, on_progress: Progress | None) -> Iterator[CellEvent]:
        """Raises KeyboardInterrupt, between two waits, once Ctrl-C or SIGTERM asked the study to stop."""
        with stop_requests() as stop:
            while (self.queue or self.in_flight) and not stop.is_set():
                while self.queue and len(self.in_flight) < self.capacity and not stop.is_set():
                    self._submit(self.queue.pop(0))
                if on_progress:
                    on_progress(list(self.progress.values()))
                done, _ = self.ray.wait(list(self.in_flight), num_returns=1, timeout=WAIT_S)
                if done:  # taken back even when a stop came meanwhile: the chunk it trained is kept
                    yield from self._take_back(done[0], submit_next=not stop.is_set())
            if stop.is_set():  # also when it came with the last chunk in flight, or while the caller held a cell
                raise KeyboardInterrupt
            if on_progress:
                on_progress(list(self.progress.values()))

    def cancel(self) -> None:
        """Stop every task; each cell it held stays resumable from its last handed-back chunk."""
        for ref in list(self.in_flight):
            self.ray.cancel(ref, force=True)
        for run_id in self.locks:
            run = open_run(self.registry, run_id)
            # a cell no chunk of which came back has trained nothing: not started, not interrupted
            run.save_card(status="interrupted" if run.card.steps_done else "created")

    def release(self) -> None:
        for lock in self.locks.values():
            lock.release()


def run_cells_on_ray(registry: Path, cells: list[tuple[str, Run]], *, workers: int | None, address: str | None,
                     eval_episodes: int, chunk_iterations: int = CHUNK_ITERATIONS,
                     on_progress: Progress | None = None, seeds_together: bool = False) -> Iterator[CellEvent]:
    """Train the unfinished `cells` on Ray; yields each cell's progress when it completes or fails. With
    `seeds_together`, a cell's unfinished seeds train in one task as one batched problem, a chunk at a time.

    Starts a local Ray instance with `workers` CPUs (and stops it after) unless `address` names a running
    cluster, or a `ray_session` around the call is connected already. Ctrl-C cancels the tasks and leaves
    every cell resumable from its last handed-back chunk."""
    with ray_session(workers, address) as ray:
        capacity = max(1, int(ray.cluster_resources().get("CPU", workers or 1)))
        driver = RayDriver(ray, registry, training_units(cells, seeds_together), capacity=capacity,
                           eval_episodes=eval_episodes, chunk_iterations=chunk_iterations)
        try:
            driver.lock_all()
            yield from driver.run(on_progress)
        except KeyboardInterrupt:
            with deferred_interrupt():  # a second Ctrl-C waits until every cell is marked resumable
                driver.cancel()
            raise
        finally:
            driver.release()


class RayExecutor:
    """The cells on Ray (studies.executor.Executor): a local instance with `workers` CPUs, or the cluster at
    `address`, one seed a task (or, with the grid's `seeds_together`, a cell's seeds in one task), in chunks
    of `chunk_iterations`."""

    def __init__(self, workers: int | None, address: str | None, eval_episodes: int,
                 chunk_iterations: int = CHUNK_ITERATIONS):
        self.workers, self.address = workers, address
        self.eval_episodes, self.chunk_iterations = eval_episodes, chunk_iterations

    def refuses(self, grid: Grid) -> str | None:
        return None  # every grid trains here

    def session(self) -> AbstractContextManager[object]:
        # connected before any run folder is created: a missing extra or an absent cluster is one line
        return ray_session(self.workers, self.address)

    def run(self, study: Study, cells: list[tuple[str, Run]], on_progress: Progress | None = None
            ) -> Iterator[CellEvent]:
        return run_cells_on_ray(study.registry, cells, workers=self.workers, address=self.address,
                                eval_episodes=self.eval_episodes, chunk_iterations=self.chunk_iterations,
                                on_progress=on_progress, seeds_together=study.grid.seeds_together)
