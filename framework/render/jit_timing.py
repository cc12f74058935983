"""Dr.Jit's kernel compilation time, measured apart from the work.

The first run in a process pays for compiling every kernel it launches (LLVM code generation
and the backend's compile); later runs of a sweep find them in Dr.Jit's cache. Comparing methods
by total time therefore charges the compilation to whichever ran first (a symbolic run at 3.56 s
first, 0.97 s next). :class:`CompileTimer` sums ``codegen_time + backend_time`` of every kernel
this process compiles while it is active (kernels found in the in-memory cache are left out: their
launch costs every render, it is not a warm-up; kernels loaded from Dr.Jit's disk cache count with
their small load time) (Dr.Jit's kernel history, drained by a background
thread every :data:`DRAIN_S` seconds so its intermediate representations do not pile up);
kernels compiled in Dask workers are not counted. It also counts those kernels
(:attr:`CompileTimer.kernels`): a loop that compiles again at every iteration shows there.
"""
from __future__ import annotations

import threading

DRAIN_S = 0.5


class CompileTimer:
    """``with CompileTimer() as t: ...``; then ``t.seconds``: Dr.Jit compilation time inside, and
    ``t.kernels``: how many kernels it compiled or loaded from the disk cache.

    Both zero when Dr.Jit has no kernel history (the flag missing from the build).
    """

    def __init__(self):
        self.seconds = 0.0
        self.kernels = 0
        self._stop = threading.Event()
        self._thread = None
        self._lock = threading.Lock()
        self._was = None

    def _drain(self) -> None:
        import drjit as dr
        with self._lock:
            for kernel in dr.kernel_history():
                if kernel.get("cache_hit") and not kernel.get("cache_disk"):   # compiled earlier in this process
                    continue
                self.seconds += (float(kernel.get("codegen_time", 0.0))
                                 + float(kernel.get("backend_time", 0.0))) / 1000.0   # ms
                self.kernels += kernel.get("type") == dr.KernelType.JIT        # not memsets, reductions

    def _loop(self) -> None:
        while not self._stop.wait(DRAIN_S):
            self._drain()

    def __enter__(self) -> CompileTimer:
        from framework.render.backend import point_at_libllvm
        point_at_libllvm()                      # before Dr.Jit's first import (libLLVM 15 aborts it)
        import drjit as dr
        flag = getattr(dr.JitFlag, "KernelHistory", None)
        if flag is None:
            return self
        self._was = dr.flag(flag)
        dr.set_flag(flag, True)
        dr.kernel_history()                     # what ran before is not this block's
        self._thread = threading.Thread(target=self._loop, name="jit-compile-timer", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        if self._thread is None:
            return
        import drjit as dr
        self._stop.set()
        self._thread.join()
        self._drain()
        dr.set_flag(dr.JitFlag.KernelHistory, bool(self._was))


def kernel_split(fn) -> tuple[float, float, object]:
    """``(wall, kernels, out)``: the seconds ``fn()`` takes and those its Dr.Jit kernels execute
    (the kernel history's ``execution_time``, summed), and its output. ``wall - kernels`` is the
    host's share: Python, numpy, transfers and waiting that no kernel overlaps. Zero kernel time
    when Dr.Jit has no kernel history."""
    import time

    import drjit as dr
    flag = getattr(dr.JitFlag, "KernelHistory", None)
    if flag is None:
        t = time.perf_counter()
        out = fn()
        return time.perf_counter() - t, 0.0, out
    was = dr.flag(flag)
    dr.set_flag(flag, True)
    dr.kernel_history()
    try:
        t = time.perf_counter()
        out = fn()
        dr.sync_thread()
        wall = time.perf_counter() - t
        kernels = sum(float(k.get("execution_time", 0.0)) for k in dr.kernel_history()) / 1000.0   # ms
    finally:
        dr.set_flag(flag, was)
    return wall, kernels, out
