"""Row operations on per-pixel coefficient matrices (CSR, one row per pixel) in O(nnz).

scipy offers ``sp.diags(s) @ m`` and ``sp.hstack(...)[:, order]`` for these; both are general
sparse products or copies (a symbolic pass, then a numeric one, then a conversion), which on the
field path's matrices took a third of a fit (2026-12-04, bundled urban_canyon_survey: 22 of 27 s of
the vignetting's expansion, the robust weights' scaling inside the Gram accumulation). Here each
is one pass over the entries.
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


def interleaved_columns(parts: list, columns: list[np.ndarray], n_columns: int) -> sp.csr_matrix:
    """``Σ_t P_t M_t``: the CSR matrices ``parts`` (same rows) side by side, column ``j`` of part
    ``t`` moved to column ``columns[t][j]`` of the result (``n_columns`` wide; the columns of all
    parts must be distinct, as when ``hstack`` is followed by a column permutation).

    Each row's entries are gathered part after part, then sorted by scipy's in-place index sort:
    canonical CSR as ``sp.csr_matrix(sp.hstack(parts)[:, order])`` gives, without its copies."""
    parts = [p.tocsr() for p in parts]
    n = parts[0].shape[0]
    counts = np.stack([np.diff(p.indptr) for p in parts])          # (T, n) entries per row and part
    indptr = np.concatenate([[0], np.cumsum(counts.sum(axis=0))])
    before = np.cumsum(counts, axis=0) - counts                    # entries of earlier parts in the row
    nnz = int(indptr[-1])
    index = np.int32 if max(nnz, n_columns) < 2**31 else np.int64
    indices, data = np.empty(nnz, index), np.empty(nnz, np.float64)
    for t, p in enumerate(parts):
        row = np.repeat(np.arange(n), counts[t])
        at = indptr[row] + before[t, row] + (np.arange(p.nnz) - p.indptr[row])
        indices[at] = np.asarray(columns[t])[p.indices]
        data[at] = p.data
    out = sp.csr_matrix((data, indices, indptr.astype(index)), shape=(n, n_columns))
    out.has_sorted_indices = False
    out.sort_indices()
    return out
