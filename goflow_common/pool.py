"""One process pool for every grid: spawned worker processes that run calls and report each one's
result, or which call failed and why, or that its worker process died.

    with ProcessPool(4) as pool:
        for index, value in pool.imap(simulate, [(seed,) for seed in range(100)]):
            ...                           # in the order the calls finish
        rows = pool.map(measure, [(gear,) for gear in gears])   # in call order

- Workers are spawned (fresh interpreters: no forked Drake, torch or thread state), each runs the
  pool's `initializer(*initargs)` once (e.g. to build its simulator), then calls from any number of
  `imap` / `map` rounds; a function and its arguments must be picklable (a module-level function).
- A call that raises is that call's failure (`WorkerError` naming the call, chained to the error);
  a worker process that dies (killed, out of memory) is noticed within about a second, its call
  started again up to `retries` times, then reported the same way (`WorkerError.pid` set), never
  waited for forever.
- Ctrl-C: the workers ignore it (no tracebacks from each of them); the driver's KeyboardInterrupt
  leaves the `with` block, which terminates the workers. A caller that wants its calls to stop
  cleanly installs its own SIGINT handling in the calls (learning.execution.PoolBackend does).

It imports no goflow package beyond goflow_common, so every layer may use it (assembly's
transition simulators, perception's calibration, learning's grids, benchmarks).
"""

from __future__ import annotations

import itertools
import multiprocessing as mp
import os
import queue
import signal
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any

from goflow_common.checks import check_int
from goflow_common.errors import GoflowError

__all__ = ["ProcessPool", "WorkerError", "map_calls"]

_EVENTS: Any = None  # a worker's queue of (task id, pid) when it starts a call


class WorkerError(GoflowError, RuntimeError):
    """A pool call failed: it raised (the exception is `__cause__`; `pid` None) or its worker
    process died on each of `attempts` starts (`pid` the last one's). `index`: the call's position."""

    def __init__(self, message: str, index: int, attempts: int = 1, pid: int | None = None) -> None:
        super().__init__(message)
        self.index, self.attempts, self.pid = index, attempts, pid


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _init_worker(events: Any, initializer: Callable[..., Any] | None, initargs: tuple) -> None:
    global _EVENTS
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _EVENTS = events
    if initializer is not None:
        initializer(*initargs)


def _tracked(task: int, fn: Callable[..., Any], args: tuple) -> Any:
    _EVENTS.put((task, os.getpid()))
    return fn(*args)


def _name(fn: Callable[..., Any]) -> str:
    return getattr(fn, "__qualname__", None) or repr(fn)


class ProcessPool:
    """`workers` spawned processes (see the module docstring); a context manager: leaving it
    normally lets the workers finish and exit, leaving it by an exception (Ctrl-C too)
    terminates them. ValueError (InputError) if `workers` is not an integer >= 1."""

    def __init__(
        self, workers: int, initializer: Callable[..., Any] | None = None, initargs: Sequence[Any] = ()
    ) -> None:
        self.workers = check_int(workers, "workers", 1)
        ctx = mp.get_context("spawn")
        self._events = ctx.SimpleQueue()
        self._pool: Any = ctx.Pool(self.workers, _init_worker, (self._events, initializer, tuple(initargs)))
        self._tasks = itertools.count()
        self._lost = False  # a worker died: its call stays in the pool's books, so close() terminates

    def __enter__(self) -> ProcessPool:
        return self

    def __exit__(self, kind: type[BaseException] | None, *rest: object) -> None:
        if kind is None:
            self.close()
        else:
            self.terminate()

    def imap(
        self,
        fn: Callable[..., Any],
        calls: Iterable[Sequence[Any]],
        *,
        retries: int = 0,
        errors: str = "raise",
        on_start: Callable[[int], None] | None = None,
    ) -> Iterator[tuple[int, Any]]:
        """Run `fn(*args)` for each `args` of `calls` in the workers; yield (index, value) as each
        finishes. A failed call (it raised, or its worker died more than `retries` times):
        `errors="raise"` raises its WorkerError (the calls still running are left to the pool:
        leave the `with` block), `errors="return"` yields it as the value. `on_start(index)` is
        called when a worker starts a call (again for each retry)."""
        if errors not in ("raise", "return"):
            raise ValueError(f"errors = {errors!r}; expected 'raise' or 'return'")
        retries = check_int(retries, "retries", 0)
        if self._pool is None:
            raise RuntimeError("the process pool is closed")
        calls = [tuple(args) for args in calls]
        results: queue.SimpleQueue = queue.SimpleQueue()
        attempts = [0] * len(calls)
        live: dict[int, int] = {}  # task id -> call index, for the calls not finished
        pids: dict[int, int] = {}  # started task -> its worker's pid
        missing: set[int] = set()  # started tasks whose worker was not alive at the last check

        def submit(index: int) -> None:
            task = next(self._tasks)
            live[task] = index
            self._pool.apply_async(
                _tracked,
                (task, fn, calls[index]),
                callback=lambda value, task=task: results.put((task, True, value)),
                error_callback=lambda exc, task=task: results.put((task, False, exc)),
            )

        for index in range(len(calls)):
            submit(index)
        checked = time.monotonic()
        while live:
            try:
                task, ok, value = results.get(timeout=0.1)
            except queue.Empty:
                task = None
            while not self._events.empty():
                started, pid = self._events.get()
                if started in live:
                    pids[started] = pid
                    attempts[live[started]] += 1
                    if on_start is not None:
                        on_start(live[started])
            if task is not None and task in live:
                index = live.pop(task)
                pids.pop(task, None)
                missing.discard(task)
                if not ok:
                    error = WorkerError(f"call {index} of {_name(fn)}: {_one_line(value)}", index, attempts[index])
                    error.__cause__ = value
                    if errors == "raise":
                        raise error
                    value = error
                yield index, value
                continue
            if task is None and pids and time.monotonic() - checked > 0.5:
                checked = time.monotonic()
                alive = {p.pid for p in mp.active_children()}
                for started, pid in list(pids.items()):
                    if pid in alive:
                        continue
                    if started not in missing:  # dead twice in a row: its result cannot be on its way
                        missing.add(started)
                        continue
                    self._lost = True
                    index = live.pop(started)
                    del pids[started]
                    missing.discard(started)
                    if attempts[index] <= retries:
                        submit(index)
                        continue
                    error = WorkerError(
                        f"call {index} of {_name(fn)}: its worker process (pid {pid}) died (killed, "
                        f"or out of memory?) on each of {attempts[index]} attempt(s)",
                        index,
                        attempts[index],
                        pid,
                    )
                    if errors == "raise":
                        raise error
                    yield index, error

    def map(self, fn: Callable[..., Any], calls: Iterable[Sequence[Any]], *, retries: int = 0) -> list[Any]:
        """`fn(*args)` for each `args` of `calls`, in call order; the first failure raises its
        WorkerError."""
        calls = list(calls)
        out: list[Any] = [None] * len(calls)
        for index, value in self.imap(fn, calls, retries=retries):
            out[index] = value
        return out

    def close(self) -> None:
        """Let the workers exit once idle and wait for them (terminates them after a worker died,
        whose call the pool would wait for). Idempotent."""
        if self._pool is not None:
            if self._lost:
                self._pool.terminate()
            else:  # terminate() would leak the workers' semaphores
                self._pool.close()
            self._pool.join()
            self._pool = None

    def terminate(self) -> None:
        """Stop the workers now and wait for them. Idempotent."""
        if self._pool is not None:
            self._pool.terminate()
            self._pool.join()
            self._pool = None


def map_calls(
    fn: Callable[..., Any],
    calls: Iterable[Sequence[Any]],
    workers: int,
    initializer: Callable[..., Any] | None = None,
    initargs: Sequence[Any] = (),
) -> list[Any]:
    """`fn(*args)` for each `args` of `calls` in a ProcessPool of min(`workers`, calls) spawned
    processes, in call order; the first failure raises its WorkerError (the other workers are
    terminated), Ctrl-C a KeyboardInterrupt once they are. No calls: [] (no pool started)."""
    calls = list(calls)
    if not calls:
        return []
    with ProcessPool(min(check_int(workers, "workers", 1), len(calls)), initializer, initargs) as pool:
        return pool.map(fn, calls)
