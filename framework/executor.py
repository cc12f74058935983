"""Where per-view work runs: in this process (``executor=serial``) or in Dask workers (``dask``).

Configuration (``framework/conf/executor/*.yaml``, ``docs/cli.md``):

``serial``
    Everything in the driver process (the default).
``dask``
    ``address: null`` starts a ``distributed.LocalCluster(n_workers, threads_per_worker,
    processes=True)`` for the run and closes it afterwards; ``address: tcp://host:port`` joins
    an existing scheduler (``Client(address)``), whose workers must be able to import this
    repository (same code, same Python environment). ``connect_timeout_s`` (default
    :data:`CONNECT_TIMEOUT_S`) bounds the wait for that scheduler (distributed's own default,
    30 s, made a wrong address look like a hang). Each task receives plain picklable data
    (the numpy :class:`~framework.scene.Scene` model, arrays, seeds), selects the Mitsuba variant
    itself and limits Dr.Jit to ``threads_per_worker`` threads (:func:`init_worker`), so the
    workers do not oversubscribe the cores.

Both executors expose :meth:`imap`: the values of one task per item, in item order, one at a
time. The caller reduces them with :class:`TreeSum` in that order, so both executors give the
same result, summed as a balanced tree while holding only O(log n) partial sums.
"""
from __future__ import annotations

import logging
from typing import Callable

from framework.errors import ConfigError, EnvironmentSetupError
from framework.render import backend

log = logging.getLogger(__name__)
CONNECT_TIMEOUT_S = 5.0


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

    def __init__(self, address: str | None = None, *, n_workers: int = 2, threads_per_worker: int = 1,
                 connect_timeout_s: float = CONNECT_TIMEOUT_S):
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


#: the schemes of a scheduler address the run accepts (distributed's TCP and TLS comms)
ADDRESS_SCHEMES = ("tcp", "tls")


def check_address(address) -> None:
    """``executor.address`` is ``null`` or ``tcp://host:port`` (``tls://`` too), port 1-65535.

    Checked before anything starts: distributed raises ``ValueError: missing port number`` or
    an unknown-scheme error only once the run is under way.

    Raises
    ------
    framework.errors.ConfigError
        Naming the address and the form to write.
    """
    if address is None:
        return
    text = str(address)
    form = "write tcp://host:port (the scheduler's address, port 8786 by default), or executor.address=null"
    scheme, sep, rest = text.partition("://")
    if not sep:
        raise ConfigError(f"executor.address={text} is not a scheduler address: {form}")
    if scheme not in ADDRESS_SCHEMES:
        raise ConfigError(f"executor.address={text}: the scheme {scheme}:// is not one a Dask scheduler "
                          f"listens on ({', '.join(s + '://' for s in ADDRESS_SCHEMES)}): {form}")
    host, colon, port = rest.rstrip("/").rpartition(":")
    if not colon or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ConfigError(f"executor.address={text} lacks a host and a port number (1-65535): {form}")


def make_executor(cfg) -> SerialExecutor:
    """The executor of the run's ``executor`` config group (None or missing: serial).

    Raises
    ------
    framework.errors.ConfigError
        For an unknown ``executor.name``, bad worker counts or connection timeout.
    framework.errors.EnvironmentSetupError
        When the scheduler at ``executor.address`` does not answer.
    """
    name = "serial" if cfg is None else str(cfg.get("name", "serial"))
    if name == "serial":
        return SerialExecutor()
    if name != "dask":
        raise ConfigError(f"executor={name} is not an executor: use serial or dask")
    n_workers, threads = cfg.get("n_workers", 2), cfg.get("threads_per_worker", 1)
    for key, value in (("n_workers", n_workers), ("threads_per_worker", threads)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ConfigError(f"executor.{key}={value} is out of range: use an integer >= 1")
    timeout = cfg.get("connect_timeout_s", CONNECT_TIMEOUT_S)
    if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not timeout > 0:
        raise ConfigError(f"executor.connect_timeout_s={timeout} is out of range: use a number of seconds > 0")
    check_address(cfg.get("address"))
    return DaskExecutor(cfg.get("address"), n_workers=n_workers, threads_per_worker=threads,
                        connect_timeout_s=timeout)
