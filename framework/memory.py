"""Handing freed memory back to the operating system.

CPython and numpy allocate through the C library's ``malloc``. glibc keeps memory freed by
arrays below its (adaptive, up to 32 MiB) mmap threshold in the process heap for reuse, so the
resident size stays at its high-water mark after large temporaries are released. On a
70-material street that retention was measured at 400 MB of a 2.0 GB peak (resident size
sampled every 0.2 s, with and without trimming). :func:`release_freed_memory` asks glibc to
return it (``malloc_trim(0)``), as Dask's workers do for their unmanaged memory; elsewhere it
does nothing.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import functools


@functools.cache
def _malloc_trim():
    """glibc's ``malloc_trim``, or None on another C library."""
    name = ctypes.util.find_library("c")
    try:
        return ctypes.CDLL(name).malloc_trim if name else None
    except (OSError, AttributeError):
        return None


def release_freed_memory() -> bool:
    """Return the heap memory freed so far to the operating system; True where it could (glibc).
    Cheap (a walk over the free lists): call it after releasing something large."""
    trim = _malloc_trim()
    if trim is None:
        return False
    trim(0)
    return True
