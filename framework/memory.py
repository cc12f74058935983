"""Handing freed memory back to the operating system, and keeping it for reuse where that pays.

CPython and numpy allocate through the C library's ``malloc``. glibc keeps memory freed by
arrays below its (adaptive, up to 32 MiB) mmap threshold in the process heap for reuse, so the
resident size stays at its high-water mark after large temporaries are released. On a
70-material street that retention was measured at 400 MB of a 2.0 GB peak (resident size
sampled every 0.2 s, with and without trimming). :func:`release_freed_memory` asks glibc to
return it (``malloc_trim(0)``), as Dask's workers do for their unmanaged memory; elsewhere it
does nothing.

The opposite holds where the same large temporaries are made again and again (the field path's
dense systems, 2,500 x 2,500 a channel): arrays above the mmap threshold are fresh mappings
each time, and every page of a fresh mapping is faulted in and zeroed by the kernel on first
write. On this project's virtual machine that first touch ran at about 0.2 GB/s, not the
memory's 10 GB/s: a 43 MB product took 0.18-0.35 s there and 0.01-0.03 s in reused memory
(bundled urban_canyon_survey, ``perf``: 17 % of the solve's CPU samples in the kernel's
``clear_page_erms``; 2026-12-06). :func:`reused_memory` keeps freed memory in the heap for the
next array during a block and returns it at the block's end.
"""
from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools

#: glibc's ``mallopt`` parameters (``malloc.h``)
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_MMAP_MAX = -1, -3, -4
#: what :func:`reused_memory` leaves after its block. Any ``mallopt`` call ends glibc's adaptive
#: thresholds for good, so the block leaves them where they settle in a process that frees large
#: arrays: the mmap threshold at its ceiling (32 MiB on 64-bit), the trim threshold at twice it
#: (glibc's manual, ``M_MMAP_THRESHOLD``); and glibc's default of 65,536 mappings
_MMAP_THRESHOLD_SETTLED, _TRIM_SETTLED, _MMAP_MAX_DEFAULT = 32 * 2**20, 64 * 2**20, 65536
#: the largest trim threshold ``mallopt`` takes (a C ``int``): heap memory is kept below it
_TRIM_NEVER = 2**31 - 1

_reusing = 0          # depth of nested :func:`reused_memory` blocks


@functools.cache
def _glibc():
    """glibc, or None on another C library (``mallopt`` and ``malloc_trim`` are glibc's)."""
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
        return libc if libc is not None and libc.malloc_trim and libc.mallopt else None
    except (OSError, AttributeError):
        return None


def release_freed_memory() -> bool:
    """Return the heap memory freed so far to the operating system; True where it could (glibc).
    Cheap (a walk over the free lists): call it after releasing something large. Inside a
    :func:`reused_memory` block it waits for the block's end (and returns True)."""
    libc = _glibc()
    if libc is None:
        return False
    if not _reusing:
        libc.malloc_trim(0)
    return True


@contextlib.contextmanager
def reused_memory():
    """Within the block, memory freed by arrays stays in the process heap and serves the next
    ones (glibc's ``mallopt``: no mmapped arrays, no trimming), where a fresh mapping would be
    faulted in and zeroed page by page (module docstring); at its end glibc's thresholds are
    where its adaptive ones settle (arrays up to 32 MiB from the heap, larger ones mapped) and the
    freed memory is returned (:func:`release_freed_memory`). The resident size inside the
    block is the heap's high-water mark. For the main thread: the settings are the process's.
    Nested blocks act as the outermost one. Elsewhere than glibc, nothing."""
    global _reusing
    libc = _glibc()
    if libc is None:
        yield
        return
    if not _reusing:
        libc.mallopt(_M_MMAP_MAX, 0)
        libc.mallopt(_M_TRIM_THRESHOLD, _TRIM_NEVER)
    _reusing += 1
    try:
        yield
    finally:
        _reusing -= 1
        if not _reusing:
            libc.mallopt(_M_MMAP_MAX, _MMAP_MAX_DEFAULT)
            libc.mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_SETTLED)
            libc.mallopt(_M_TRIM_THRESHOLD, _TRIM_SETTLED)
            release_freed_memory()
