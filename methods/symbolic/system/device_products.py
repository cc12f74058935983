"""Products of per-pixel coefficient matrices (CSR) with dense matrices on the run's Dr.Jit device
(``llvm_*`` and ``cuda_*`` alike): the products of the std's per-pixel scores
(:mod:`methods.symbolic.uncertainty.sandwich_meat`) computed where the run renders.

One lane per entry ``(i, l)`` of the result walks row ``i``'s stored entries in their order and
sums ``m_ij x_jl`` from 0, one product and one sum at a time, as scipy's own CSR kernels
(``csr_matvec``, ``csr_matvecs``) do: the same operations in the same order, so the sums do not
depend on the device's scheduling, and on a CPU they are scipy's bits (a test compares them).
What crosses to the device is the matrices' stored entries and ``x``; what comes back is the
dense result.

Several products are launched together (:func:`device_products`): their kernels are recorded
first and evaluated at once, so a GPU runs them back to back and the host waits once.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import scipy.sparse as sp

from methods.symbolic.system.pixel_matrices import FactoredColumns

#: the lanes, entries and indices of a product are 32-bit on the device
_LIMIT = 2 ** 32 - 1


def device_products(pairs: list) -> list[np.ndarray]:
    """``[m @ x for m, x in pairs]`` on the Dr.Jit backend of the active Mitsuba variant.

    Parameters
    ----------
    pairs : list of (matrix, numpy.ndarray)
        Each a CSR ``(n, N)`` matrix (or a :class:`~methods.symbolic.system.pixel_matrices.FactoredColumns`,
        its factors' product on the device) and an ``(N,)`` or ``(N, k)`` float ``x``.

    Returns
    -------
    list of numpy.ndarray
        ``(n,)`` or ``(n, k)`` float64 each, as ``m @ x`` gives.

    Raises
    ------
    ValueError
        If no JIT variant (``llvm_*`` or ``cuda_*``) is active, a
        matrix is neither CSR nor factored, or the shapes do not match.
    """
    if not (mi.variant() or "").startswith(("llvm", "cuda")):
        raise ValueError(f"device_products needs an llvm_* or cuda_* Mitsuba variant active, not "
                         f"{mi.variant()!r}: call mi.set_variant first")
    jobs = [_Job(m, x) for m, x in pairs]
    recorded = [_product(job.csr, job.x) for job in jobs]
    dr.eval(*recorded)                                   # one evaluation for every product
    return [job.result(out) for job, out in zip(jobs, recorded)]


class _Job:
    """One product ``m @ x``: a CSR ``m`` as it is, a factored one as ``Σ_t diag(s_t) (m x_t)``
    with ``x_t`` the rows of ``x`` copy ``t``'s columns hold (one product of ``m`` with the
    ``T`` stacked ``x_t``, its column blocks scaled and summed on the host)."""

    def __init__(self, m, x: np.ndarray):
        x = np.asarray(x, dtype=np.float64)
        if x.ndim not in (1, 2):
            raise ValueError(f"device_products: x must be a vector or a matrix, got {x.ndim} dimensions")
        self.vector, self.m = x.ndim == 1, m
        x2 = x.reshape(x.shape[0], -1)
        if m.shape[1] != x2.shape[0]:
            raise ValueError(f"device_products: shapes {m.shape} and {x.shape} do not match")
        if isinstance(m, FactoredColumns):
            self.csr, self.k = m.m, x2.shape[1]
            self.x = np.hstack([x2[cols] for cols in m.columns])
        elif sp.isspmatrix_csr(m) or isinstance(m, sp.csr_array):
            self.csr, self.k, self.x = m, x2.shape[1], x2
        else:
            raise ValueError(f"device_products: the matrix must be CSR or FactoredColumns, not {type(m).__name__}")

    def result(self, out) -> np.ndarray:
        """The evaluated product ``out`` of :func:`_product` as ``m @ x`` shapes it."""
        n, K = self.csr.shape[0], self.x.shape[1]
        p = np.array(out.numpy()).reshape(n, K) if n * K else np.zeros((n, K))
        if isinstance(self.m, FactoredColumns):
            blocks = [p[:, t * self.k:(t + 1) * self.k] * s[:, None] for t, s in enumerate(self.m.scales)]
            p = sum(blocks[1:], blocks[0])
        return p.ravel() if self.vector else p


def _product(m: sp.csr_matrix, x: np.ndarray):
    """``m @ x`` (``x`` ``(N, K)`` C-ordered) as a recorded ``mi.Float64`` of ``n K`` entries, row-major.
    Every size enters the kernel opaque: one kernel for every shape."""
    n, K = m.shape[0], x.shape[1]
    if max(n * K, m.nnz, x.size) > _LIMIT:
        raise ValueError(f"device_products: a product of {n} x {K} entries from {m.nnz} stored ones exceeds "
                         "the device's 32-bit indices; split the matrix's rows")
    if n * K == 0:
        return mi.Float64()
    indptr = mi.UInt32(np.asarray(m.indptr, np.uint32))
    entries = max(m.nnz, 1)                     # Dr.Jit arrays of size 0 cannot be gathered from
    indices = mi.UInt32(np.resize(np.asarray(m.indices, np.uint32), entries))
    data = mi.Float64(np.resize(np.asarray(m.data, np.float64), entries))
    X = mi.Float64(np.ascontiguousarray(x).ravel())
    k = dr.opaque(mi.UInt32, K)
    lane = dr.arange(mi.UInt32, n * K)
    row = lane // k
    column = lane - row * k
    start, stop = dr.gather(mi.UInt32, indptr, row), dr.gather(mi.UInt32, indptr, row + 1)

    def body(j, total):
        # scipy's order: total = total + m_ij * x_jl, the entries of the row in turn
        value = dr.gather(mi.Float64, data, j) * dr.gather(mi.Float64, X, dr.gather(mi.UInt32, indices, j) * k + column)
        return j + 1, total + value

    _, total = dr.while_loop(state=(start, dr.zeros(mi.Float64, n * K)), cond=lambda j, total: j < stop,
                             body=body, labels=("j", "total"), label="device product")
    return total
