"""Where per-view work runs: in this process (``executor=serial``) or in Dask workers (``dask``).

Options: :mod:`framework.executor_options` (``serial``: everything in the driver process, the
default; ``dask``: a ``distributed.LocalCluster(n_workers, threads_per_worker, processes=True)``
started for the run and closed afterwards, or the existing scheduler at ``address``, whose workers
must be able to import this repository). Each task receives plain picklable data (the numpy
:class:`~framework.scene.Scene` model, arrays, seeds), selects the Mitsuba variant itself and
limits Dr.Jit to ``threads_per_worker`` threads (:func:`init_worker`), so the workers do not
oversubscribe the cores.

Both executors expose :meth:`imap`: the values of one task per item, in item order, one at a
time. The caller reduces them with :class:`TreeSum` in that order, so both executors give the
same result, summed as a balanced tree while holding only O(log n) partial sums.
"""
from __future__ import annotations

import logging
from typing import Callable

from framework.errors import EnvironmentSetupError
from framework.executor_options import DaskOptions, executor_options
from framework.render import backend

log = logging.getLogger(__name__)


def init_worker(variant: str, threads: int | None) -> None:
    """Select ``variant`` (with a usable libLLVM) and cap Dr.Jit's thread pool in this process."""
    backend.set_variant(str(variant))
    if threads:
        import drjit as dr
        if dr.thread_count() != int(threads):
            dr.set_thread_count(int(threads))


class TreeSum:
    """Pairwise (tree) sum of values arriving one at a time, e.g. the views' Gram systems.

    Values are combined like the carries of a binary counter: the i-th value joins partial sums
    of 1, 2, 4... earlier values, so the association depends only on the arrival order (serial
    and Dask give the same bits), the rounding error grows as O(log n) rather than O(n), and at
    most ``log2(n) + 1`` partial sums are held (memory stays flat in the number of views).
    """

    def __init__(self):
        self._partial: list[tuple[int, object]] = []      # (number of values, their sum)

    def add(self, value) -> None:
        """Add ``value``; it is consumed: a partial sum may be updated in place (``+=``), which
        lets a large value (a Gram system) release its memory channel by channel as it is added."""
        count = 1
        while self._partial and self._partial[-1][0] == count:
            n, older = self._partial.pop()
            older += value
            value, count = older, count + n
        self._partial.append((count, value))

    def total(self, empty=None):
        """The sum of every value added (``empty`` when none was)."""
        out = None
        for _, value in reversed(self._partial):
            if out is not None:
                value += out
            out = value
        self._partial = []
        return empty if out is None else out


class SerialExecutor:
    """Runs tasks in the calling process."""

    name = "serial"
    threads_per_worker = None
    tasks_here = 1          # tasks running at once on this machine (memory checks multiply by it)

    def imap(self, fn: Callable, items: list, **kwargs):
        """Values of ``fn(item)`` in item order, one at a time (the caller can drop each before
        the next arrives, so memory does not grow with the number of items)."""
        for item in items:
            yield fn(item, **kwargs)

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
    connect_timeout_s : float
        Seconds to wait for the scheduler at ``address`` (also distributed's reconnection window).

    Raises
    ------
    framework.errors.EnvironmentSetupError
        When no scheduler answers at ``address`` within ``connect_timeout_s``.
    """

    name = "dask"

    def __init__(self, address: str | None = DaskOptions.address, *, n_workers: int = DaskOptions.n_workers,
                 threads_per_worker: int = DaskOptions.threads_per_worker,
                 connect_timeout_s: float = DaskOptions.connect_timeout_s):
        from distributed import Client, LocalCluster
        self.threads_per_worker = int(threads_per_worker)
        self._cluster = None
        # a remote scheduler's workers run elsewhere: this machine's memory is not theirs
        self.tasks_here = 0 if address else int(n_workers)
        if address:
            self.client = _connect(str(address), connect_timeout_s)
        else:
            self._cluster = LocalCluster(n_workers=int(n_workers), threads_per_worker=self.threads_per_worker,
                                         processes=True, dashboard_address=None)
            self.client = Client(self._cluster)
        log.info("dask executor: %s", self.client)

    def imap(self, fn: Callable, items: list, **kwargs):
        """All tasks submitted at once; values yielded in item order, each future released
        once its value is here."""
        # pure=False: every item is its own task even when two items hash alike
        handles = [self.client.submit(fn, item, pure=False, **kwargs) for item in items]
        for i in range(len(handles)):
            value = handles[i].result()
            handles[i].release()
            yield value

    def close(self) -> None:
        self.client.close()
        if self._cluster is not None:
            self._cluster.close()


def _connect(address: str, timeout_s: float):
    """``Client(address)``, or one line saying the scheduler is unreachable (distributed raises
    OSError "Timed out trying to connect" after ``timeout_s``)."""
    from distributed import Client
    try:
        return Client(address, timeout=float(timeout_s))
    except (OSError, TimeoutError):
        raise EnvironmentSetupError(f"the Dask scheduler at {address} is unreachable (no answer in "
                                    f"{timeout_s:g} s): start one (dask scheduler) or drop executor.address"
                                    ) from None


def make_executor(options) -> SerialExecutor:
    """The executor of the run's ``executor`` options (:func:`executor_options`: a built
    :class:`~framework.executor_options.DaskOptions`, or the config group, None or missing: serial).

    Raises
    ------
    framework.errors.ConfigError
        For an unknown ``executor.name`` or a bad option (:func:`executor_options`).
    framework.errors.EnvironmentSetupError
        When the scheduler at ``executor.address`` does not answer.
    """
    options = executor_options(options)
    if options.name == "serial":
        return SerialExecutor()
    return DaskExecutor(options.address, n_workers=options.n_workers, threads_per_worker=options.threads_per_worker,
                        connect_timeout_s=options.connect_timeout_s)
