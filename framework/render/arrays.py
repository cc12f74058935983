"""Host arrays handed to Dr.Jit at 64-byte aligned addresses, so that a kernel does not depend on
where numpy put them."""
from __future__ import annotations

import numpy as np

ALIGNMENT = 64
_NUMPY = {"Float32": np.float32, "Float64": np.float64, "UInt32": np.uint32, "Int32": np.int32, "Bool": np.bool_}


def device_array(kind, values):
    """``kind(values)`` (a flat Dr.Jit array type, a numpy array or sequence) read from a
    ``ALIGNMENT``-byte aligned copy of ``values`` in ``kind``'s element type.

    Why: on ``llvm_*`` Dr.Jit maps a numpy array's memory instead of copying it (``dr.copy`` of
    the result keeps the mapping), and declares the packet loads of a kernel that reads it
    ``align 64`` when the address is a multiple of 64 and ``align 1`` otherwise. The same
    expression then compiles to two kernels chosen by where numpy's allocator put the array, so a
    later run of a process compiles its kernels again (measured: ``align 64`` against ``align 1``
    for one expression on arrays 4 bytes apart, 0.19 s for the pass kernel). On ``cuda_*`` the
    constructor copies to the device, where the alignment is Dr.Jit's own.
    """
    import drjit as dr
    if not dr.is_array_v(kind) or dr.depth_v(kind) != 1:
        raise TypeError(f"device_array: kind {kind.__name__} is not a flat Dr.Jit array type (Float, UInt32, ...); "
                        "pass each component of a nested type on its own")
    name = dr.type_v(kind).name
    if name not in _NUMPY:
        raise TypeError(f"device_array: kind {kind.__name__} has element type {name}; use one of {', '.join(_NUMPY)}")
    dtype = np.dtype(_NUMPY[name])
    a = np.asarray(values)
    nbytes = a.size * dtype.itemsize
    buf = np.empty(nbytes + ALIGNMENT, np.uint8)
    start = -buf.ctypes.data % ALIGNMENT
    out = buf[start:start + nbytes].view(dtype).reshape(a.shape)
    out[...] = a                        # the one copy, converting to kind's element type (as astype)
    return kind(out)

