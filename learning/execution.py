"""Where a grid of independent jobs runs: this process, a local process pool, or a Ray cluster.

A grid is a list of `Job`s (a module-level function, its arguments, a name and the resources it
needs); `run_grid(jobs, backend)` runs them and returns their results in job order, whatever order
they finish in. Every job is seeded by its own arguments, so the backends give the same results:

- `InlineBackend()`: one job after the other in this process;
- `PoolBackend(workers)`: `workers` spawned processes on this machine (the default of the grids:
  nothing beyond Python's standard library);
- `RayBackend(address, workers)`: each job a Ray task with its CPUs (and GPUs) declared. Address
  "local" starts a Ray on this machine with `workers` CPUs; "auto" or "HOST:PORT" joins a running
  cluster (`ray start --head` on one node, `ray start --address HOST:PORT` on the others).

Failures: a job that raises is reported with its one-line message and the others go on; `run_grid`
raises GridError once the grid has ended. A job whose worker process dies (killed, out of memory,
node lost) is started again, up to `retries` times; a training run resumes from its last
checkpoint, so its result is the one of an uninterrupted run. Progress: one bar over the grid with
the number of jobs running, done, retried and failed, and a line above it for each retry and failure.

Ray is imported only when a RayBackend starts (`pip install -e ".[ray]"`). A job runs in the
driver's working directory on every node, so relative paths mean the same there; on a cluster of
several machines, that folder and every output path must be on storage all nodes mount (NFS or
similar; docs/cluster.md).
"""

from __future__ import annotations

import argparse
import ipaddress
import os
import re
import socket
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from goflow_common.checks import check_int, check_number
from goflow_common.errors import ClusterError, GridError, InputError
from goflow_common.pool import ProcessPool, WorkerError

__all__ = [
    "Job",
    "Outcome",
    "Backend",
    "InlineBackend",
    "PoolBackend",
    "RayBackend",
    "parse_ray_address",
    "make_backend",
    "add_ray_flag",
    "run_jobs",
    "run_grid",
]

#: What --ray accepts, for help texts and messages.
RAY_CHOICES = (
    "'local' (start Ray on this machine with --workers CPUs), 'auto' (join the Ray cluster this "
    "machine belongs to) or HOST:PORT (the head of a running cluster, e.g. 10.0.0.5:6379)"
)


@dataclass(frozen=True)
class Job:
    """One job of a grid: `fn(*args, **kwargs)` under `name`, needing `num_cpus` CPUs and `num_gpus`
    GPUs while it runs. `fn` must be a module-level function and the arguments picklable (a worker
    receives them by pickle), and the job deterministic in its arguments, so that where it runs,
    and a retry after its worker died, do not change its result."""

    name: str
    fn: Callable[..., Any]
    args: tuple[Any, ...] = ()
    kwargs: dict[str, Any] = field(default_factory=dict)
    num_cpus: float = 1.0
    num_gpus: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise InputError(f"Job.name = {self.name!r}; expected a non-empty string")
        if not callable(self.fn):
            raise InputError(f"Job {self.name}: fn = {self.fn!r}; expected a function")
        object.__setattr__(self, "args", tuple(self.args))
        check_number(self.num_cpus, f"Job {self.name}: num_cpus", 0.0)
        check_number(self.num_gpus, f"Job {self.name}: num_gpus", 0.0)


@dataclass
class Outcome:
    """How one job of a grid ended."""

    name: str
    status: str  # "done", "failed", or "stopped" (Ctrl-C before or while it ran)
    value: Any = None  # the job's result when done
    error: str = ""  # "Type: message" on one line when failed
    seconds: float = 0.0  # wall time of its last attempt, measured in the worker
    attempts: int = 0  # times it was started (2 or more: its worker died and it was run again)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _call(job: Job) -> tuple[str, Any, str, float]:
    """Run `job` here: (status, value, error, seconds). An exception is the job's failure, not the
    worker's; KeyboardInterrupt goes through."""
    t0 = time.perf_counter()
    try:
        value = job.fn(*job.args, **job.kwargs)
    except Exception as exc:
        return "failed", None, _one_line(exc), time.perf_counter() - t0
    return "done", value, "", time.perf_counter() - t0


# ---------------------------------------------------------------------------------------------
# Progress: one bar, the state of every job
# ---------------------------------------------------------------------------------------------


class _Board:
    """The driver's view of a grid: each job's state and attempts, one tqdm bar over the grid
    (done + failed of all) whose postfix counts the jobs running, done, retried and failed, and a
    line above the bar for each retry and each failure. `on_result(index, value)` is called for
    each job as it finishes."""

    def __init__(
        self, jobs: Sequence[Job], progress: bool, desc: str, on_result: Callable[[int, Any], None] | None
    ) -> None:
        from tqdm import tqdm

        self.names = [job.name for job in jobs]
        self.state = ["pending"] * len(jobs)
        self.attempts = [0] * len(jobs)
        self.progress, self.desc, self.on_result = progress, desc, on_result
        self.bar = tqdm(total=len(jobs), disable=not progress, desc=desc, unit="run", file=sys.stderr)
        self._show()

    def _say(self, text: str) -> None:
        if self.progress:
            self.bar.write(f"{self.desc}: {text}", file=sys.stderr)

    def _show(self, refresh: bool = True) -> None:
        running = self.state.count("running")
        retried = sum(a > 1 for a in self.attempts)
        self.bar.set_postfix_str(
            f"running {running}, done {self.state.count('done')}, retried {retried}, "
            f"failed {self.state.count('failed')}",
            refresh=refresh,
        )

    def started(self, index: int, attempt: int | None = None) -> None:
        """Job `index` started (its `attempt`-th start; default: one more than before)."""
        attempt = self.attempts[index] + 1 if attempt is None else attempt
        if attempt <= self.attempts[index] or self.state[index] in ("done", "failed", "stopped"):
            return
        if attempt > 1:
            self._say(
                f"{self.names[index]}: its worker died; started again (attempt {attempt}), from its last "
                "checkpoint where it keeps one"
            )
        self.attempts[index] = attempt
        self.state[index] = "running"
        self._show()

    def finished(self, index: int, outcome: Outcome) -> None:
        outcome.attempts = max(outcome.attempts, self.attempts[index], 1)
        self.attempts[index] = outcome.attempts
        self.state[index] = outcome.status
        if outcome.status == "failed":
            self._say(f"{outcome.name}: failed: {outcome.error}")
        self._show(refresh=outcome.status == "stopped")
        if outcome.status != "stopped":
            self.bar.update(1)
        if outcome.status == "done" and self.on_result is not None:
            self.on_result(index, outcome.value)

    def close(self) -> None:
        self.bar.close()


# ---------------------------------------------------------------------------------------------
# Backends
# ---------------------------------------------------------------------------------------------


class Backend:
    """Where `run_jobs` runs a grid. A backend is a reentrant context manager: entering it the
    first time starts what it needs (Ray: starts or joins a cluster), leaving it the last time
    stops that; `run_jobs` enters it itself, so that a caller who enters it first (to connect
    before any output is written, or to run several grids on one cluster) keeps it open."""

    def __init__(self) -> None:
        self._depth = 0

    def __enter__(self) -> Backend:
        if self._depth == 0:
            self.start()
        self._depth += 1
        return self

    def __exit__(self, *exc: object) -> None:
        self._depth -= 1
        if self._depth == 0:
            self.stop()

    def start(self) -> None:
        """Make the backend ready (nothing for the local ones)."""

    def stop(self) -> None:
        """Release what `start` took."""

    def run(self, jobs: Sequence[Job], board: _Board) -> list[Outcome]:
        """Run every job; report starts and ends to `board`; return the outcomes in job order."""
        raise NotImplementedError


class InlineBackend(Backend):
    """One job after the other in this process (Ctrl-C interrupts the job in progress)."""

    def __repr__(self) -> str:
        return "InlineBackend()"

    def run(self, jobs: Sequence[Job], board: _Board) -> list[Outcome]:
        outcomes = []
        for i, job in enumerate(jobs):
            board.started(i)
            status, value, error, seconds = _call(job)
            outcomes.append(Outcome(job.name, status, value, error, seconds))
            board.finished(i, outcomes[-1])
        return outcomes


_STOP: Any = None  # a pool worker's view of the grid's stop event


def _init_pool_worker(stop: Any) -> None:
    """A pool worker skips the jobs left once the grid is stopped (it ignores Ctrl-C except while
    it runs a job: `_pool_call`; goflow_common.pool ignores it between jobs)."""
    global _STOP
    _STOP = stop


def _pool_call(job: Job) -> tuple[str, Any, str, float]:
    """One job in a pool worker; "stopped" when the grid was interrupted (a training run keeps
    its last checkpoint)."""
    import signal

    if _STOP is not None and _STOP.is_set():
        return "stopped", None, "", 0.0
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return _call(job)
    except KeyboardInterrupt:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        return "stopped", None, "", 0.0
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)


class PoolBackend(Backend):
    """`workers` spawned processes on this machine (a goflow_common.pool.ProcessPool), one job each
    at a time.

    Ctrl-C stops every job at its next step (a training run keeps its last checkpoint), skips the
    jobs not started, lets the workers exit on their own (nothing is killed mid-write) and then
    raises KeyboardInterrupt. A job whose worker process dies is started again in a fresh worker,
    up to `retries` times."""

    def __init__(self, workers: int = 2, retries: int = 3) -> None:
        super().__init__()
        self.workers = check_int(workers, "workers", 1)
        self.retries = check_int(retries, "retries", 0)

    def __repr__(self) -> str:
        return f"PoolBackend(workers={self.workers})"

    def run(self, jobs: Sequence[Job], board: _Board) -> list[Outcome]:
        import multiprocessing as mp
        import signal
        import threading

        stop, done = mp.get_context("spawn").Event(), threading.Event()
        pool = ProcessPool(min(self.workers, len(jobs)), _init_pool_worker, (stop,))

        def forward() -> None:
            # Until the pool has drained, tell the workers every second (a Ctrl-C in a terminal has
            # reached them already; a signal to this process alone has not): an interrupt that lands
            # inside a finalizer is swallowed by Python, and the job would go on.
            while not done.wait(1.0):
                for child in mp.active_children():
                    try:
                        os.kill(child.pid, signal.SIGINT)
                    except ProcessLookupError:
                        pass

        def interrupt(signum: int, frame: Any) -> None:
            if not stop.is_set():
                stop.set()
                threading.Thread(target=forward, daemon=True).start()

        main_thread = threading.current_thread() is threading.main_thread()
        previous = signal.signal(signal.SIGINT, interrupt) if main_thread else None
        outcomes: list[Outcome | None] = [None] * len(jobs)
        try:
            for i, result in pool.imap(
                _pool_call, [(job,) for job in jobs], retries=self.retries, errors="return", on_start=board.started
            ):
                if isinstance(result, WorkerError):
                    error = (
                        (
                            f"WorkerDied: its worker process (pid {result.pid}) died on each of {result.attempts} "
                            "attempts"
                        )
                        if result.pid is not None
                        else _one_line(result.__cause__ or result)
                    )
                    outcomes[i] = Outcome(jobs[i].name, "failed", error=error)
                else:
                    status, value, error, seconds = result
                    outcomes[i] = Outcome(jobs[i].name, status, value, error, seconds)
                board.finished(i, outcomes[i])
        except BaseException:
            pool.terminate()
            raise
        finally:
            done.set()
            if main_thread:
                signal.signal(signal.SIGINT, previous)
        pool.close()
        if stop.is_set():
            raise KeyboardInterrupt
        return [o for o in outcomes if o is not None]


def _import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise ClusterError(
            "--ray needs the ray package, which is not installed; install it with "
            '`.venv/bin/pip install -e ".[ray]"` (or use the local process pool: leave --ray '
            "out)"
        ) from None
    return ray


class _StartLog:
    """A Ray actor counting the starts of each task of a grid (a count above 1: a retry)."""

    def __init__(self) -> None:
        self.starts: dict[int, int] = {}

    def reset(self) -> None:
        self.starts = {}

    def started(self, index: int) -> None:
        self.starts[index] = self.starts.get(index, 0) + 1

    def snapshot(self) -> dict[int, int]:
        return dict(self.starts)


def _ray_call(log: Any, index: int, job: Job, cwd: str) -> tuple[str, Any, str, float]:
    """A job as a Ray task: report the start, run in the driver's working directory. (The report is
    not waited for: a task blocked in ray.get gives its CPU back, and Ray would start another
    task on it.)"""
    log.started.remote(index)
    try:
        os.chdir(cwd)
    except OSError:
        return (
            "failed",
            None,
            (
                f"ClusterError: the driver's working directory {cwd} does not exist on node "
                f"{socket.gethostname()}: run the driver from a folder on storage every node "
                "mounts (docs/cluster.md)"
            ),
            0.0,
        )
    return _call(job)


class RayBackend(Backend):
    """Each job a Ray task with its CPUs and GPUs declared; a task whose worker dies is run again
    up to `retries` times (a training run resumes from its last checkpoint).

    `address`: "local" starts a Ray on this machine with `workers` CPUs (default: all) and stops it
    when the backend is left; "auto" or "HOST:PORT" joins a running cluster, whose CPUs decide how
    many jobs run at once. No cluster at HOST:PORT is a ClusterError at `start`, before anything is
    written. If this process is already connected to Ray, that connection is used and kept."""

    def __init__(self, address: str = "local", workers: int | None = None, retries: int = 3) -> None:
        super().__init__()
        self.address = parse_ray_address(address)
        self.workers = None if workers is None else check_int(workers, "workers", 1)
        self.retries = check_int(retries, "retries", 0)
        self._owned = False
        self._task: Any = None
        self._log: Any = None  # the _StartLog actor, one for the grids of this backend

    def __repr__(self) -> str:
        return f"RayBackend({self.address!r}, workers={self.workers})"

    def start(self) -> None:
        import logging

        if self.address not in ("local", "auto"):
            _check_reachable(self.address)
        ray = _import_ray()
        if ray.is_initialized():
            return
        common = dict(include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR, namespace="goflow")
        if self.address == "local":
            ray.init(num_cpus=self.workers, **common)
        else:
            try:
                ray.init(address=self.address, **common)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise ClusterError(
                    f"--ray {self.address}: cannot join a Ray cluster ({_one_line(exc)}); start one "
                    "with `ray start --head`, or use --ray local"
                ) from None
        self._owned = True

    def stop(self) -> None:
        ray = _import_ray()
        if self._log is not None and ray.is_initialized():
            ray.kill(self._log)
        self._log = None
        if self._owned:
            ray.shutdown()
            self._owned = False

    def run(self, jobs: Sequence[Job], board: _Board) -> list[Outcome]:
        ray = _import_ray()
        have = ray.cluster_resources()
        for job in jobs:  # a task asking for more than the cluster has would wait forever
            for key, need in (("CPU", job.num_cpus), ("GPU", job.num_gpus)):
                if need > have.get(key, 0.0):
                    raise ClusterError(
                        f"job {job.name} needs {need:g} {key}s; the Ray cluster has {have.get(key, 0.0):g} in all"
                    )
        if self._task is None:
            self._task = ray.remote(_ray_call)
        if self._log is None:
            self._log = ray.remote(num_cpus=0)(_StartLog).remote()
        log = self._log
        ray.get(log.reset.remote())
        cwd = os.getcwd()
        index = {}
        for i, job in enumerate(jobs):
            ref = self._task.options(
                name=job.name,
                num_cpus=job.num_cpus,
                num_gpus=job.num_gpus,
                max_retries=self.retries,
                retry_exceptions=False,
            ).remote(log, i, job, cwd)
            index[ref] = i
        outcomes: list[Outcome | None] = [None] * len(jobs)
        pending = list(index)
        try:
            while pending:
                ready, pending = ray.wait(pending, num_returns=1, timeout=0.5)
                for i, starts in ray.get(log.snapshot.remote()).items():
                    board.started(i, starts)
                for ref in ready:
                    i = index[ref]
                    try:
                        status, value, error, seconds = ray.get(ref)
                    except ray.exceptions.RayError as exc:
                        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
                        status, value, seconds = "failed", None, 0.0
                        error = f"{type(exc).__name__}: {first} (after {max(board.attempts[i], 1)} attempts)"
                    outcomes[i] = Outcome(jobs[i].name, status, value, error, seconds)
                    board.finished(i, outcomes[i])
        except KeyboardInterrupt:
            for ref in pending:
                ray.cancel(ref)
            raise
        return [o for o in outcomes if o is not None]


def _check_reachable(address: str) -> None:
    """ClusterError at once when nothing accepts a connection at `address` (Ray's own connect
    retries for minutes)."""
    host, _, port = address.rpartition(":")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=5).close()
    except OSError as exc:
        raise ClusterError(
            f"--ray {address}: no Ray cluster answers there ({exc.strerror or exc}); start one with "
            f"`ray start --head --port {port}` on that machine, or use --ray local"
        ) from None


# ---------------------------------------------------------------------------------------------
# --ray: one flag, one check, one factory
# ---------------------------------------------------------------------------------------------

_LABEL = r"[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
_HOSTNAME = re.compile(rf"(?=.{{1,253}}\Z){_LABEL}(\.{_LABEL})*")  # RFC 1123 names and IPv4 addresses


def parse_ray_address(value: Any, name: str = "--ray") -> str:
    """`value` as a Ray address: "local", "auto", or HOST:PORT with HOST a hostname, an IPv4
    address or a bracketed IPv6 address and PORT in 1..65535. InputError naming `name` and what is
    accepted otherwise (the Ray client's ray:// is refused: the driver runs on a cluster node)."""
    expected = f"expected {RAY_CHOICES}"
    if not isinstance(value, str):
        raise InputError(f"{name} = {value!r}; {expected}")
    if value in ("local", "auto"):
        return value
    if "://" in value:
        raise InputError(
            f"{name} = {value!r}: a URL is not accepted (run this command on a node of the cluster, "
            f"with its head's HOST:PORT); {expected}"
        )
    host, sep, port = value.rpartition(":")
    ok_port = sep and port.isascii() and port.isdigit() and 1 <= int(port) <= 65535
    if host.startswith("[") and host.endswith("]"):
        try:
            ok_host = ipaddress.ip_address(host[1:-1]).version == 6
        except ValueError:
            ok_host = False
    else:
        ok_host = _HOSTNAME.fullmatch(host) is not None
    if not (ok_port and ok_host):
        raise InputError(f"{name} = {value!r}; {expected}")
    return value


def make_backend(ray: str | None = None, workers: int = 1, inline: bool = False) -> Backend:
    """The backend of a `--ray` value and `--workers`: Ray at that address (`workers` CPUs when it
    is "local"), else a process pool of `workers` (or this process, when `inline` and `workers`
    is 1). Checks both; InputError for a bad value. Nothing starts before the backend is entered."""
    workers = check_int(workers, "--workers", 1)
    if ray is not None:
        address = parse_ray_address(ray)
        return RayBackend(address, workers if address == "local" else None)
    return InlineBackend() if inline and workers == 1 else PoolBackend(workers)


def add_ray_flag(parser: argparse.ArgumentParser) -> None:
    """Add --ray, the same on every command that runs a grid (`args.ray`, None by default)."""
    parser.add_argument(
        "--ray",
        default=None,
        metavar="local|auto|HOST:PORT",
        help=f"run each job as a Ray task: {RAY_CHOICES}; default: local processes (docs/cluster.md)",
    )


# ---------------------------------------------------------------------------------------------
# Running a grid
# ---------------------------------------------------------------------------------------------


def run_jobs(
    jobs: Sequence[Job],
    backend: Backend,
    progress: bool = True,
    desc: str = "grid",
    on_result: Callable[[int, Any], None] | None = None,
) -> list[Outcome]:
    """Run `jobs` on `backend` (entered for the call); return each job's Outcome in job order.

    A job that fails does not stop the others. `on_result(index, value)` is called in this process
    as each job finishes (to save results as they come). Ctrl-C: KeyboardInterrupt once the
    workers have stopped (the pool lets each training run keep its last checkpoint)."""
    jobs = list(jobs)
    if not all(isinstance(job, Job) for job in jobs):
        raise InputError("run_jobs: jobs must be Job instances")
    if not isinstance(backend, Backend):
        raise InputError(f"run_jobs: backend = {backend!r}; expected a Backend (make_backend)")
    if not jobs:
        return []
    with backend:
        board = _Board(jobs, progress, desc, on_result)
        try:
            return backend.run(jobs, board)
        finally:
            board.close()


def run_grid(
    jobs: Sequence[Job],
    backend: Backend,
    progress: bool = True,
    desc: str = "grid",
    on_result: Callable[[int, Any], None] | None = None,
) -> list[Any]:
    """The results of `jobs` in job order (see `run_jobs`). If any job failed, GridError once all
    have ended, naming each failed job with its message (`.results` holds the others')."""
    outcomes = run_jobs(jobs, backend, progress, desc, on_result)
    failed = {o.name: o.error for o in outcomes if o.status == "failed"}
    results = [o.value if o.status == "done" else None for o in outcomes]
    if failed:
        listing = "; ".join(f"{name}: {error}" for name, error in failed.items())
        raise GridError(
            f"{len(failed)} of {len(outcomes)} jobs failed, the others finished: {listing}", failed, results
        )
    return results
