"""Scaling and interleaving per-pixel coefficient matrices (CSR, one row per pixel) in O(nnz).

scipy offers ``sp.diags(s) @ m``, ``m @ sp.diags(f)`` and ``sp.hstack(...)[:, order]`` for these;
each is a general sparse product or a copy through another format (a symbolic pass, a numeric
one, a conversion), which on the field path's matrices added up to a large share of a fit
(bundled urban_canyon_survey, 2026-12-04: 22 of the vignetting expansion's 27 s went to the
hstack and column permutation). Here each is one pass over the entries.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def scale_rows(m, s: np.ndarray) -> sp.csr_matrix:
    """``diag(s) m`` for a CSR ``m``: row ``i`` times ``s[i]``. Entries that become 0 are dropped,
    as scipy's product drops them (a pixel of weight 0 adds nothing to a Gram product)."""
    m = m.tocsr()
    s = np.asarray(s, np.float64).reshape(m.shape[0])
    out = sp.csr_matrix((m.data * np.repeat(s, np.diff(m.indptr)), m.indices.copy(), m.indptr.copy()),
                        shape=m.shape)
    out.eliminate_zeros()
    return out


def scale_columns(m, f: np.ndarray) -> sp.csr_matrix:
    """``m diag(f)`` for a CSR ``m``: column ``j`` times ``f[j]``, entries that become 0 dropped."""
    m = m.tocsr()
    out = sp.csr_matrix((m.data * np.asarray(f, np.float64)[m.indices], m.indices.copy(), m.indptr.copy()),
                        shape=m.shape)
    out.eliminate_zeros()
    return out


def expanded_columns(m, scales: np.ndarray, columns: np.ndarray, n_columns: int) -> sp.csr_matrix:
    """``Σ_t diag(scales[t]) m P_t``: each entry ``(i, j)`` of the CSR ``m`` copied to the ``T``
    columns ``columns[t, j]``, scaled by its row's ``scales[t, i]`` (``n_columns`` wide; the
    ``columns`` must all differ, as a column permutation of ``hstack`` of the ``T`` scaled copies
    gives). Entries that become 0 are dropped. A row's entries stay in the order of the copies,
    not sorted by column: the sparse products and scalings that take these matrices do not need
    sorted indices, and sorting every row cost 7.5 s of a 160 s solve (bundled
    urban_canyon_survey, 2026-12-05; scipy sorts them where an operation needs it).

    Parameters
    ----------
    m : scipy.sparse matrix
        ``(n, N)``.
    scales : numpy.ndarray
        ``(T, n)`` row factors of the copies.
    columns : numpy.ndarray
        ``(T, N)`` int, the column of each copy of each column of ``m``.
    n_columns : int
        Width of the result.
    """
    m = m.tocsr()
    scales, columns = np.asarray(scales, np.float64), np.asarray(columns)
    T = len(scales)
    row = np.repeat(np.arange(m.shape[0]), np.diff(m.indptr))
    data = (m.data[:, None] * scales[:, row].T).ravel()          # entry e's copies side by side
    index = np.int32 if max(m.nnz * T, n_columns) < 2**31 else np.int64
    out = sp.csr_matrix((data, columns[:, m.indices].T.ravel().astype(index), (T * m.indptr).astype(index)),
                        shape=(m.shape[0], n_columns))
    out.has_sorted_indices = False         # each row's copies interleave: left unsorted (docstring)
    out.eliminate_zeros()
    return out
