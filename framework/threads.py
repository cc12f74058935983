"""Threads of this process for work whose heavy part releases the GIL (scipy's sparse kernels,
numpy's large array operations): the symbolic solve's sparse products and its per-pixel scores.

The number of tasks a caller splits its work into is the caller's and fixed, so results do not
depend on the thread count of the machine (only on which tasks there are, summed in their order).
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterable, Iterator

#: most threads of the pool (the solve's tasks come in 2-4 parts)
MAX_THREADS = 4

_POOL: ThreadPoolExecutor | None = None


def _forget_pool() -> None:
    """A forked child has none of its parent's threads: it starts a pool of its own when it needs one."""
    global _POOL
    _POOL = None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool)


def cores() -> int:
    """Cores this process may run on (its CPU affinity where the platform has it)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def run_threads(tasks: list[Callable[[], object]]) -> list:
    """The values of the callables ``tasks``, in order: on a shared pool of up to
    ``min(cores(), MAX_THREADS)`` threads, or in turn on one core or for a single task. A task
    must not itself call :func:`run_threads` (it would wait on the pool it occupies)."""
    global _POOL
    n = min(cores(), MAX_THREADS)
    if n < 2 or len(tasks) < 2:
        return [task() for task in tasks]
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=n, thread_name_prefix="symbolic")
    return [future.result() for future in [_POOL.submit(task) for task in tasks]]


def two_at_a_time(items: Iterable) -> Iterator[tuple]:
    """``items`` in consecutive pairs, the last alone when they are odd in number: work split so
    that two parts run side by side on :func:`run_threads` (three channels on two cores leave one
    idle a third of the time)."""
    items = iter(items)
    for first in items:
        second = next(items, None)
        yield (first,) if second is None else (first, second)


class Chain:
    """Steps ``value = step(value)``, from ``value``, run one after another in a background thread
    while the caller goes on: :meth:`then` waits for the step in flight (at most one: what it holds
    stays bounded) and starts the next; :meth:`result` waits for the last and raises what a step
    raised. The steps run in the order given, so the result does not depend on timing. A context
    manager: its thread ends on leaving it."""

    def __init__(self, value=None, name: str = "chain"):
        self._pool = ThreadPoolExecutor(1, thread_name_prefix=name)
        self._value, self._pending = value, None

    def then(self, step: Callable[[object], object]) -> None:
        self._pending = self._pool.submit(step, self._wait())

    def _wait(self):
        pending, self._pending = self._pending, None
        if pending is not None:
            self._value = pending.result()
        return self._value

    def result(self):
        return self._wait()

    def __enter__(self) -> "Chain":
        return self

    def __exit__(self, *exc) -> None:
        self._pool.shutdown()          # after an error too: the step in flight ends first
