"""Scaling and interleaving per-pixel coefficient matrices (CSR, one row per pixel) in O(nnz).

scipy offers ``sp.diags(s) @ m``, ``m @ sp.diags(f)`` and ``sp.hstack(...)[:, order]`` for these;
each is a general sparse product or a copy through another format (a symbolic pass, a numeric
one, a conversion), which on the field path's matrices added up to a large share of a fit
(bundled urban_canyon_survey, 2026-12-04: 22 of the vignetting expansion's 27 s went to the
hstack and column permutation). Here each is one pass over the entries. :class:`FactoredColumns`
keeps a lens's expansion as its factors, for products that need no copies.
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


def moved_columns(m, position: np.ndarray, factor: float = 1.0) -> sp.csr_matrix:
    """``m`` with column ``j`` moved to column ``position[j]`` (a permutation) and every entry times
    ``factor``: ``m P`` for the permutation matrix ``P``, in one pass over the entries; the rows'
    entries are left in their order (unsorted, marked so), as :func:`expanded_columns` leaves them
    (scipy's sparse product for it: 0.33 of a survey fit's 1.3 s views, 2026-12-05)."""
    m = m.tocsr()
    position = np.asarray(position)
    index = m.indices.dtype if len(position) < np.iinfo(m.indices.dtype).max else np.int64
    out = sp.csr_matrix((m.data * float(factor), position[m.indices].astype(index), m.indptr.copy()),
                        shape=(m.shape[0], len(position)))
    out.has_sorted_indices = False
    if factor == 0.0:
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


#: :meth:`FactoredColumns._sparse_product` folds its copies in a dense array when that holds at most
#: this many entries per stored entry of the product; a sparse fold sorts each row (bundled
#: urban_canyon_survey, 2026-12-05: a fit's std, when it took these products, 3.2 s in them sparse,
#: 2.9 s dense, serial)
FOLD_DENSE = 4


class FactoredColumns:
    """The matrix :func:`expanded_columns` gives, ``Σ_t diag(s_t) m P_t``, kept as its factors.

    A lens to estimate expands every coefficient into ``T`` scaled copies
    (:func:`~methods.symbolic.survey.vignetting.with_factors`); most of what a fit does with
    them is a product, which the factors give without the copies: ``E x = Σ_t s_t ⊙ (m x_t)``
    with ``x_t = P_t x`` the rows of ``x`` copy ``t``'s columns hold, and ``Eᵀ v`` puts
    ``mᵀ(s_t ⊙ v)`` at copy ``t``'s columns. Expanding a fit's views took 1.1 s of each
    fit of bundled urban_canyon_survey (2026-12-05), whose summed systems come from the factors
    (:func:`~methods.symbolic.system.view_systems.dense_sum`) and half of whose fits use nothing
    else. Anything but ``@`` and a row slice (``indptr``, ``tocsr()``, a column or fancy index)
    is the expanded matrix's, made on first use and kept.

    Parameters
    ----------
    m : scipy.sparse matrix
        ``(n, N)`` CSR, the matrix before the expansion.
    scales, columns, n_columns
        As for :func:`expanded_columns`.
    """

    def __init__(self, m, scales: np.ndarray, columns: np.ndarray, n_columns: int):
        self.m, self.scales, self.columns = m.tocsr(), np.asarray(scales, np.float64), np.asarray(columns)
        self.shape = (self.m.shape[0], int(n_columns))
        self._expanded = None

    def expanded(self) -> sp.csr_matrix:
        """The expanded matrix (:func:`expanded_columns`), made once."""
        if self._expanded is None:
            self._expanded = expanded_columns(self.m, self.scales, self.columns, self.shape[1])
        return self._expanded

    def __getattr__(self, name: str):
        if name.startswith("__") or name in ("m", "scales", "columns", "shape", "_expanded"):
            raise AttributeError(name)      # not set yet (unpickling), or a protocol scipy probes
        return getattr(self.expanded(), name)

    def __getitem__(self, key):
        if isinstance(key, slice) and key.step in (None, 1):     # rows: the factors' rows
            lo, hi, _ = key.indices(self.shape[0])
            return FactoredColumns(self.m[lo:hi], self.scales[:, lo:hi], self.columns, self.shape[1])
        return self.expanded()[key]

    def __matmul__(self, x):
        if isinstance(x, FactoredColumns) or not (isinstance(x, np.ndarray) or sp.issparse(x)):
            return self.expanded() @ (x.expanded() if isinstance(x, FactoredColumns) else x)
        if sp.issparse(x):
            return self._sparse_product(x)
        parts = [rows_times(self.m @ x[cols], s) for s, cols in zip(self.scales, self.columns)]
        return sum(parts[1:], parts[0])

    def _sparse_product(self, x) -> sp.csr_matrix:
        """``E x`` for a sparse ``x`` ``(n_columns, D)``: one product ``m [x_0 … x_{T-1}]``, each
        of its entries then scaled by its row's ``s_t`` and folded onto column ``d``. A survey fit's
        std took 3.3 s so, 3.9 s as ``T`` scaled products and their sparse sums, 2.6 s from the
        expanded matrix plus 1.1 s to expand it (bundled urban_canyon_survey, 2026-12-05)."""
        n, D = self.shape[0], x.shape[1]
        x = x.tocsr()
        p = (self.m @ sp.hstack([x[cols] for cols in self.columns], format="csr")).tocsr()
        row = np.repeat(np.arange(n), np.diff(p.indptr))
        copy, column = np.divmod(p.indices, D)
        data = p.data * self.scales[copy, row]
        if n * D <= FOLD_DENSE * p.nnz:     # few columns: summed into a dense array, no sort of each row
            return sp.csr_matrix(np.bincount(row * D + column, weights=data, minlength=n * D).reshape(n, D))
        out = sp.csr_matrix((data, column, p.indptr), shape=(n, D))
        out.sum_duplicates()
        out.eliminate_zeros()
        return out

    @property
    def T(self) -> "_Transposed":
        return _Transposed(self)


class _Transposed:
    """``Eᵀ`` of a :class:`FactoredColumns` ``E``: ``Eᵀ v`` for a vector from the factors, any
    other product from the expanded matrix."""

    def __init__(self, of: FactoredColumns):
        self.of = of
        self.shape = of.shape[::-1]

    def __matmul__(self, v):
        if not (isinstance(v, np.ndarray) and v.ndim == 1):
            return self.of.expanded().T @ (v.expanded() if isinstance(v, FactoredColumns) else v)
        out = np.zeros(self.shape[0])
        for s, cols in zip(self.of.scales, self.of.columns):
            out[cols] = self.of.m.T @ (s * v)        # the copies' columns differ: no two terms meet
        return out


#: a product of coefficients with a Jacobian of at most this many columns (parameters) takes the
#: Jacobian dense, and the scores and derivatives made from it stay dense: there the sparse
#: matrices' bookkeeping (sparse products, products with diagonals, sums, conversions) costs more
#: than the zeros (bundled urban_canyon_survey, 17 parameters, 2026-12-05: a fit's std 4.7 s
#: serial sparse, 2.0 s dense; its fit quality 3.3 s sparse)
DENSE_JACOBIAN_COLUMNS = 64


def dense_jacobian(J) -> bool:
    """Whether products with the Jacobian ``J`` take it dense (:data:`DENSE_JACOBIAN_COLUMNS`)."""
    return J.shape[1] <= DENSE_JACOBIAN_COLUMNS


def stored_per_row(m) -> np.ndarray:
    """``(n + 1,)`` cumulative count of a CSR matrix's stored entries by row (its ``indptr``); of a
    :class:`FactoredColumns`, that of its copies (``T`` per entry), not expanded for it."""
    if isinstance(m, FactoredColumns):
        return len(m.scales) * m.m.indptr
    return m.indptr


def rows_times(p, s: np.ndarray):
    """``diag(s) p`` of a vector, a dense matrix or a sparse one (CSR, :func:`scale_rows`)."""
    if sp.issparse(p):
        return scale_rows(p, s)
    return p * (s if p.ndim == 1 else s[:, None])


#: largest bound on a product's non-zeros :func:`product_into` allocates for (12 bytes each);
#: above it the product takes scipy's own two passes
PRODUCT_BOUND_ENTRIES = 32 * 2**20


def product_into(dense: np.ndarray, p, q) -> None:
    """``dense += p @ q`` for CSR ``p`` ``(M, K)`` and ``q`` ``(K, N)``, in place.

    scipy's ``p @ q`` runs its product kernel twice: once to count the result's non-zeros
    (``csr_matmat_maxnnz``), once to form them (``csr_matmat``). Here the count is a bound, row
    ``i`` at most ``min(N, Σ_k nnz(q_k))`` over the ``k`` of ``p``'s row ``i`` (``O(nnz(p))``),
    the kernel runs once into buffers of that size, and each row's entries are added where they
    sit in ``dense`` (the kernel emits each of a row's columns once, unsorted). The same kernel
    on the same operands: the same values as ``p @ q``. On the field path's lens products
    (bundled urban_canyon_survey, 2026-12-06) the counting pass was a third of the products' CPU
    time. Above :data:`PRODUCT_BOUND_ENTRIES` (or where scipy lacks the kernel) ``p @ q``, its
    entries added the same way.
    """
    if not dense.flags.c_contiguous or dense.shape != (p.shape[0], q.shape[1]):
        raise ValueError(f"dense must be a C-contiguous {p.shape[0]} x {q.shape[1]} array (got {dense.shape})")
    p, q = p.tocsr(), q.tocsr()
    M, N = p.shape[0], q.shape[1]
    work = np.diff(q.indptr)[p.indices]
    reach = np.concatenate([[0], np.cumsum(work, dtype=np.int64)])
    bound = int(np.minimum(reach[p.indptr[1:]] - reach[p.indptr[:-1]], N).sum())
    kernel = _product_kernel()
    if kernel is None or bound > PRODUCT_BOUND_ENTRIES:
        m = (p @ q).tocsr()
        m.sum_duplicates()          # canonical: a repeated entry would be added once
        indptr, indices, data = m.indptr, m.indices, m.data
    else:
        index = np.int32 if max(bound, M, N, p.shape[1], p.nnz, q.nnz) < 2**31 else np.int64
        indptr, indices, data = np.empty(M + 1, index), np.empty(bound, index), np.empty(bound)
        kernel(M, N, p.indptr.astype(index, copy=False), p.indices.astype(index, copy=False),
               p.data.astype(np.float64, copy=False), q.indptr.astype(index, copy=False),
               q.indices.astype(index, copy=False), q.data.astype(np.float64, copy=False), indptr, indices, data)
    nnz = int(indptr[-1])
    rows = np.repeat(np.arange(M), np.diff(indptr))
    dense.reshape(-1)[rows * dense.shape[1] + indices[:nnz]] += data[:nnz]


def _product_kernel():
    """scipy's CSR product kernel (``scipy.sparse._sparsetools.csr_matmat``), or None."""
    try:
        from scipy.sparse._sparsetools import csr_matmat
    except ImportError:
        return None
    return csr_matmat
