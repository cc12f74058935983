"""Where per-view work runs: in this process (``executor=serial``) or in Dask workers (``dask``).

Configuration (``framework/conf/executor/*.yaml``, CONTRACT section 2):

``serial``
    Everything in the driver process (the default).
``dask``
    ``address: null`` starts a ``distributed.LocalCluster(n_workers, threads_per_worker,
    processes=True)`` for the run and closes it afterwards; ``address: tcp://host:port`` joins
    an existing scheduler (``Client(address)``), whose workers must be able to import this
    repository (same code, same Python environment). Each task receives plain picklable data
    (the numpy :class:`~framework.scene.Scene` model, arrays, seeds), selects the Mitsuba variant
    itself and limits Dr.Jit to ``threads_per_worker`` threads (:func:`init_worker`), so the
    workers do not oversubscribe the cores.

Both executors expose the same calls: :meth:`map` (one task per item, handles in item
order), :meth:`imap` (values in item order, one at a time), :meth:`gather` (handles -> values)
and :meth:`tree_reduce` (pairwise sum of handles as a balanced binary tree; on Dask the
additions run on the workers).
"""
from __future__ import annotations

import logging
import operator
from typing import Any, Callable

log = logging.getLogger(__name__)


def init_worker(variant: str, threads: int | None) -> None:
    """Select ``variant`` (with a usable libLLVM) and cap Dr.Jit's thread pool in this process."""
    from framework import backend
    backend.set_variant(str(variant))
    if threads:
        import drjit as dr
        if dr.thread_count() != int(threads):
            dr.set_thread_count(int(threads))


def _pairs(items: list, add: Callable) -> list:
    """One level of a pairwise reduction: ``[add(a0, a1), add(a2, a3), ..., (last)]``."""
    out = [add(items[i], items[i + 1]) for i in range(0, len(items) - 1, 2)]
    if len(items) % 2:
        out.append(items[-1])
    return out


class SerialExecutor:
    """Runs tasks in the calling process; handles are the values themselves."""

    name = "serial"
    threads_per_worker = None

    def map(self, fn: Callable, items: list, **kwargs) -> list:
        return [fn(item, **kwargs) for item in items]

    def imap(self, fn: Callable, items: list, **kwargs):
        """Values of ``fn(item)`` in item order, one at a time (the caller can drop each before
        the next arrives, so memory does not grow with the number of items)."""
        for item in items:
            yield fn(item, **kwargs)

    def gather(self, handles: list) -> list:
        return list(handles)

    def tree_reduce(self, handles: list, op: Callable = operator.add) -> Any:
        """Pairwise tree sum (same tree shape as :class:`DaskExecutor`); None for no handle."""
        items = list(handles)
        while len(items) > 1:
            items = _pairs(items, op)
        return items[0] if items else None

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class DaskExecutor(SerialExecutor):
    """Runs tasks on a dask.distributed cluster (a local one, or an existing scheduler).

    Parameters
    ----------
    address : str or None
        ``tcp://host:port`` of an existing scheduler; None starts a ``LocalCluster``.
    n_workers : int
        Worker processes of the local cluster.
    threads_per_worker : int
        Threads per worker, and Dr.Jit threads each task may use.
    """

    name = "dask"

    def __init__(self, address: str | None = None, *, n_workers: int = 2, threads_per_worker: int = 1):
        from distributed import Client, LocalCluster
        self.threads_per_worker = int(threads_per_worker)
        self._cluster = None
        if address:
            self.client = Client(str(address))
        else:
            self._cluster = LocalCluster(n_workers=int(n_workers), threads_per_worker=self.threads_per_worker,
                                         processes=True, dashboard_address=None)
            self.client = Client(self._cluster)
        log.info("dask executor: %s", self.client)

    def map(self, fn: Callable, items: list, **kwargs) -> list:
        # pure=False: every item is its own task even when two items hash alike
        return [self.client.submit(fn, item, pure=False, **kwargs) for item in items]

    def gather(self, handles: list) -> list:
        return self.client.gather(list(handles))

    def imap(self, fn: Callable, items: list, **kwargs):
        """All tasks submitted at once; values yielded in item order, each future released
        once its value is here."""
        handles = self.map(fn, items, **kwargs)
        for i in range(len(handles)):
            value = handles[i].result()
            handles[i].release()
            yield value

    def tree_reduce(self, handles: list, op: Callable = operator.add) -> Any:
        """Pairwise tree sum computed on the workers; returns the gathered value."""
        items = list(handles)
        if not items:
            return None
        while len(items) > 1:
            items = _pairs(items, lambda a, b: self.client.submit(op, a, b, pure=False))
        return self.client.gather(items[0])

    def close(self) -> None:
        self.client.close()
        if self._cluster is not None:
            self._cluster.close()


def make_executor(cfg) -> SerialExecutor:
    """The executor of the run's ``executor`` config group (None or missing: serial).

    Raises
    ------
    framework.errors.ConfigError
        For an unknown ``executor.name`` or bad worker counts.
    """
    from framework.errors import ConfigError
    name = "serial" if cfg is None else str(cfg.get("name", "serial"))
    if name == "serial":
        return SerialExecutor()
    if name != "dask":
        raise ConfigError(f"executor={name} is not an executor: use serial or dask")
    n_workers, threads = cfg.get("n_workers", 2), cfg.get("threads_per_worker", 1)
    for key, value in (("n_workers", n_workers), ("threads_per_worker", threads)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ConfigError(f"executor.{key}={value} is out of range: use an integer >= 1")
    return DaskExecutor(cfg.get("address"), n_workers=n_workers, threads_per_worker=threads)
