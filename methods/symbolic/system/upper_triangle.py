"""Sparse symmetric matrices stored as their upper triangle (diagonal included).

A Gram matrix ``G = Σ_i γ_i γ_iᵀ`` is symmetric: its triangle holds half the entries (a
228-weight street: 13.6M instead of 27.1M a channel) and makes the Gauss-Newton product
``Jᵀ G J`` about 3x faster (:func:`sandwich`). Here: the triangle of a matrix (:func:`upper`,
:func:`triangle`), the products of the whole matrix from it (:func:`symmetric_dot`,
:func:`sandwich`), its principal submatrix (:func:`principal`) and its rows and columns moved
into a larger index set (:func:`spread`), each without forming the other triangle.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from framework.threads import run_threads


def principal(g: sp.spmatrix, idx: np.ndarray) -> sp.csr_matrix:
    """``g[idx][:, idx]`` for an increasing ``idx`` (so the triangle of G stays a triangle), ``g``
    itself when ``idx`` is every row. The rows are taken by scipy, the columns by a lookup of each
    kept entry (scipy's column fancy-indexing of CSR is several times slower and holds more
    temporaries)."""
    g, idx = g.tocsr(), np.asarray(idx, dtype=np.int64)
    if len(idx) == g.shape[0] and np.array_equal(idx, np.arange(g.shape[0])):
        return g
    if np.any(np.diff(idx) <= 0):
        raise ValueError("principal: idx must be strictly increasing")
    new = np.full(g.shape[1], -1, dtype=np.int64)
    new[idx] = np.arange(len(idx))
    rows = g[idx]
    col = new[rows.indices]
    keep = col >= 0
    row = np.repeat(np.arange(len(idx)), np.diff(rows.indptr))[keep]
    indptr = np.concatenate([[0], np.cumsum(np.bincount(row, minlength=len(idx)))])
    index = np.int32 if max(len(idx), int(keep.sum())) < 2**31 else np.int64
    return sp.csr_matrix((rows.data[keep], col[keep].astype(index), indptr.astype(index)),
                         shape=(len(idx), len(idx)))


def upper(g) -> sp.csr_matrix:
    """The upper triangle (diagonal included) of a symmetric ``g`` as float64 CSR: ``g`` itself
    when it has no entry below the diagonal (checked on each row's first column, O(rows))."""
    g = sp.csr_matrix(g, dtype=np.float64)
    g.sum_duplicates()                                   # sorted column indices, no duplicates
    filled = np.flatnonzero(np.diff(g.indptr) > 0)
    if np.all(g.indices[g.indptr[filled]] >= filled):
        return g
    return triangle(g)


def triangle(g) -> sp.csr_matrix:
    """The upper triangle (diagonal included) of ``g`` as CSR, built by filtering its entries."""
    g = g.tocsr()
    n = g.shape[0]
    row = np.repeat(np.arange(n, dtype=np.int64), np.diff(g.indptr))
    keep = g.indices >= row
    indptr = np.concatenate([[0], np.cumsum(np.bincount(row[keep], minlength=n))])
    return sp.csr_matrix((g.data[keep], g.indices[keep], indptr), shape=g.shape)


def dense_triangle(m: np.ndarray) -> sp.csr_matrix:
    """The upper triangle (diagonal included) of the dense square ``m`` as CSR, exact zeros left
    out. Its entries taken row by row in the triangle's order need no sort: 0.04 s against
    0.24 s for scipy's ``csr_matrix(np.triu(m))`` at 2,568 monomials (2026-12-05)."""
    n = m.shape[0]
    index = np.int32 if n * (n + 1) // 2 < 2**31 else np.int64
    rows, cols = np.triu_indices(n)
    indptr = np.concatenate([[0], np.cumsum(np.arange(n, 0, -1))]).astype(index)
    out = sp.csr_matrix((m[rows, cols], cols.astype(index), indptr), shape=(n, n))
    out.eliminate_zeros()
    return out


def dense_symmetric(u) -> np.ndarray:
    """The whole symmetric matrix whose upper triangle is ``u``, dense (both triangles, the
    diagonal once; no sparse sum of the triangles): ``u`` made dense and :func:`mirror_upper`."""
    return mirror_upper(u.toarray())


def mirror_upper(dense: np.ndarray) -> np.ndarray:
    """The square ``dense`` made symmetric in place from its upper triangle (the diagonal
    included), whatever its lower one held; returns it. The lower triangle is copied from the
    upper one a block of :data:`MIRROR_BLOCK` rows at a time, which stays in cache: 10 ms against
    35 ms for ``dense + dense.T`` at 2,160 monomials (2026-12-05), the same entries."""
    for i in range(0, dense.shape[0], MIRROR_BLOCK):
        dense[i:i + MIRROR_BLOCK, :i] = dense[:i, i:i + MIRROR_BLOCK].T
        square = dense[i:i + MIRROR_BLOCK, i:i + MIRROR_BLOCK]
        lower = np.tril_indices(len(square), -1)
        square[lower] = square.T[lower]
    return dense


#: rows of a block :func:`dense_symmetric` mirrors at once
MIRROR_BLOCK = 128


def symmetric_dot(u: sp.csr_matrix, x: np.ndarray, diagonal: np.ndarray | None = None) -> np.ndarray:
    """``G x`` for the symmetric ``G`` whose upper triangle is ``u``: ``U x + Uᵀ x - diag(U) x``
    (``x``: ``(N,)`` or ``(N, k)``; ``diagonal``: ``u.diagonal()`` when the caller keeps it).
    The two products run on two threads (scipy's sparse kernels release the GIL)."""
    d = u.diagonal() if diagonal is None else diagonal
    ux, utx = run_threads([lambda: u @ x, lambda: u.T @ x])
    return ux + utx - (d * x if np.ndim(x) == 1 else d[:, None] * x)


def sandwich(u: sp.csr_matrix, J: sp.spmatrix, diagonal: np.ndarray | None = None) -> sp.csr_matrix:
    """Sparse ``Jᵀ G J`` for the symmetric ``G`` whose upper triangle is ``u``:
    ``S + Sᵀ - Jᵀ diag(U) J`` with ``S = Jᵀ U J`` (the Gauss-Newton matrix, and a change of
    monomials' ``Mᵀ G M``).

    ``S`` is summed over :data:`PRODUCT_PARTS` row ranges of ``u`` (``J_kᵀ (U_k J)``, views of
    ``u``'s arrays), computed on up to that many threads: the sum's order does not depend on the
    thread count, and each range's ``U_k J`` temporary is a fraction of the whole. Measured on
    a 296-weight street's first pass (310,822 monomials, 15.5M stored entries a channel, 2
    cores): 1.10 s on one thread, 0.59 s on two. Storing the triangle only made it about 3x
    faster than ``Jᵀ (G J)`` with both triangles stored (1.59 s → 0.51 s at 228 weights).
    """
    u, J = u.tocsr(), J.tocsr()

    def part(lo: int, hi: int):
        return J[lo:hi].T @ (_rows(u, lo, hi) @ J)

    parts = run_threads([lambda lo=lo, hi=hi: part(lo, hi) for lo, hi in _row_ranges(u.indptr, PRODUCT_PARTS)])
    S = parts[0]
    for p in parts[1:]:
        S = S + p
    return (S + S.T - J.T @ sp.diags(u.diagonal() if diagonal is None else diagonal) @ J).tocsr()


#: row ranges of G's triangle a sparse product is split into (:func:`sandwich`): a fixed number,
#: so its result does not depend on the thread count of the machine it runs on
PRODUCT_PARTS = 4


def _row_ranges(indptr: np.ndarray, parts: int) -> list[tuple[int, int]]:
    """``parts`` contiguous ``(lo, hi)`` row ranges of a CSR matrix with about equal non-zeros
    (empty ranges left out)."""
    n = len(indptr) - 1
    cuts = np.searchsorted(indptr, np.linspace(0, indptr[-1], parts + 1)[1:-1], side="right") - 1
    edges = np.unique(np.concatenate([[0], np.clip(cuts, 0, n), [n]]))
    return [(int(lo), int(hi)) for lo, hi in zip(edges[:-1], edges[1:])]


def _rows(u: sp.csr_matrix, lo: int, hi: int) -> sp.csr_matrix:
    """Rows ``lo:hi`` of ``u`` sharing its values and column indices (scipy's slicing copies them)."""
    a, b = u.indptr[lo], u.indptr[hi]
    return sp.csr_matrix((u.data[a:b], u.indices[a:b], u.indptr[lo:hi + 1] - a), shape=(hi - lo, u.shape[1]),
                         copy=False)


def spread(g: sp.csr_matrix, pos: np.ndarray, n: int) -> sp.csr_matrix:
    """``g`` with row and column ``i`` moved to ``pos[i]`` (increasing) in an ``(n, n)`` matrix.

    Built in CSR directly, sharing ``g``'s values: an increasing ``pos`` keeps every row's
    columns in order, so only the row pointers and column indices are new (a COO round trip
    holds 3-4 copies of a 200 MB matrix at once)."""
    g = g.tocsr()
    counts = np.zeros(n + 1, dtype=np.int64)
    counts[np.asarray(pos) + 1] = np.diff(g.indptr)
    index = np.int32 if max(n, g.nnz) < 2**31 else np.int64
    return sp.csr_matrix((g.data, np.asarray(pos, index)[g.indices], np.cumsum(counts).astype(index)),
                         shape=(n, n), copy=False)
