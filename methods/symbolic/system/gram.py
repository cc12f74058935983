"""Normal equations of the least-squares cost (paper eq. 6, p = 2) in the monomial basis.

With the pixel polynomials ``L_i(ρ) = γ_i · μ(ρ)`` (eq. 8; ``μ(ρ)`` the vector of monomials) and
observed pixels ``y_i``, the cost of one channel is

    ε²(ρ) = Σ_i (γ_i·μ - y_i)² = μᵀ G μ - 2 bᵀ μ + yy,   G = Σ_i γ_i γ_iᵀ,  b = Σ_i y_i γ_i,  yy = Σ_i y_i²

so the pixels are summed once; the solver never touches them again and memory does not depend
on the pixel count. G lives over the monomials that occur only, as one sparse matrix per channel,
and only its upper triangle (diagonal included) is stored: G is symmetric, and the triangle holds
half the entries (a 228-weight street: 13.6M instead of 27.1M a channel) and makes the
Gauss-Newton product ``Jᵀ G J`` about 3x faster (:mod:`methods.symbolic.system.upper_triangle`).
A view's system is formed from its coefficients by :mod:`methods.symbolic.system.view_systems`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from framework.threads import run_threads
from methods.symbolic.system import dense_gram
from methods.symbolic.system.dense_gram import Triangles, psd_projection, triangle_nnz
from methods.symbolic.system.upper_triangle import dense_symmetric, dense_triangle, mirror_upper, principal, spread, \
    triangle, upper

log = logging.getLogger(__name__)


#: components of G with more used monomials than this are not PSD-projected (dense eigh: O(n³))
PSD_BLOCK_LIMIT = 4000
#: with ``threads``, the channels of a Gram accumulation after the first are formed side by side
#: only when the first one's triangle took at most this many bytes. Measured 2026-12-04 on the
#: 296-weight street (bench section 5, K = 21, default method, its pass's systems): peak RSS 1906 MiB
#: one channel at a time, 2111 with all three side by side, 2033 with this bound; the field path's
#: view systems on the bundled survey and misfit scenes are below it
PARALLEL_CHANNEL_BYTES = 64 * 2**20


@dataclass
class GramSystem:
    """Per-channel Gram system ``(G, b, yy)`` of the cost ``μᵀGμ - 2bᵀμ + yy`` over the monomials
    ``codes``.

    Attributes
    ----------
    G : list of scipy.sparse.csr_matrix
        One ``(N, N)`` float64 matrix per channel, the **upper triangle** (diagonal included) of
        the symmetric ``Σ_i γ_i γ_iᵀ`` (``N = len(codes)``, the monomials that occur: most pairs
        never share a pixel, so G is sparse). Given full (symmetric) to the constructor, it is
        cut to its triangle; :meth:`matrix` gives the whole matrix back,
        :func:`~methods.symbolic.system.upper_triangle.symmetric_dot` its product.
    b : numpy.ndarray
        ``(C, N)`` float64, ``Σ_i y_i γ_i``.
    yy : numpy.ndarray
        ``(C,)`` float64, ``Σ_i y_i²``.
    n_pixels : int
        Number of pixels accumulated.
    codes : numpy.ndarray
        ``(N,)`` sorted int64 labels of the columns: the monomials' multiset codes
        (:class:`~methods.symbolic.system.basis.MonomialBasis`); systems over different codes add by
        merging them.
    psd_skipped : tuple of int
        Sizes of the components :meth:`psd` left unprojected (above its limit).
    dense : list of numpy.ndarray or None
        The whole symmetric ``(N, N)`` matrices, when the system is held dense
        (:meth:`from_dense`, :mod:`~methods.symbolic.system.dense_gram`): ``G`` is then given as
        None and cut from them where a step asks for it (:class:`~methods.symbolic.system.dense_gram.Triangles`).
    """

    G: list
    b: np.ndarray
    yy: np.ndarray
    n_pixels: int = 0
    codes: np.ndarray | None = None
    psd_skipped: tuple = ()
    dense: list | None = None

    def __post_init__(self):
        if self.codes is None:
            self.codes = np.arange(self.b.shape[1], dtype=np.int64)
        if self.dense is not None:
            self.dense = list(self.dense)
            for d in self.dense:            # shared by the systems made from it: never written
                d.setflags(write=False)
            self.G = Triangles(self.dense)
        else:
            self.G = [upper(g) for g in self.G]

    @classmethod
    def zeros(cls, codes, n_channels: int) -> "GramSystem":
        """An empty system (no pixel) over ``codes`` (or ``range(codes)`` for an int)."""
        codes = np.arange(codes, dtype=np.int64) if np.ndim(codes) == 0 else np.asarray(codes, np.int64)
        N = len(codes)
        return cls([sp.csr_matrix((N, N)) for _ in range(n_channels)], np.zeros((n_channels, N)),
                   np.zeros(n_channels), 0, codes)

    @classmethod
    def from_dense(cls, G: np.ndarray, b: np.ndarray, yy: np.ndarray, n_pixels: int, codes) -> "GramSystem":
        """A system held dense (``dense``) from ``(C, N, N)`` symmetric matrices ``G``, taken
        over (their upper triangles count: each is mirrored in place), ``b`` ``(C, N)``, ``yy`` ``(C,)``."""
        return cls(None, np.asarray(b, np.float64), np.asarray(yy, np.float64), int(n_pixels),
                   np.asarray(codes, np.int64), dense=[mirror_upper(g) for g in G])

    @property
    def n_monomials(self) -> int:
        return len(self.codes)

    @property
    def n_channels(self) -> int:
        return len(self.G)

    @property
    def nnz(self) -> int:
        """Stored entries of G (one triangle), all channels."""
        if self.dense is not None:
            return int(sum(triangle_nnz(d) for d in self.dense))
        return int(sum(g.nnz for g in self.G))

    def diagonals(self) -> np.ndarray:
        """``(C, N)``: the diagonal of each ``G_c``."""
        return np.stack([d.diagonal() for d in (self.dense if self.dense is not None else self.G)])

    def matrix(self, c: int) -> sp.csr_matrix:
        """The whole symmetric ``G_c`` (both triangles): for inspection and tests."""
        g = self.G[c]
        return (g + g.T - sp.diags(g.diagonal())).tocsr()

    def accumulate(self, coeffs: np.ndarray, observed: np.ndarray, mask: np.ndarray | None = None, *,
                   coeffs_b: np.ndarray | None = None) -> "GramSystem":
        """Add pixels given as dense coefficients in place (returns ``self``).

        With ``coeffs_b``, an independent estimate of the same coefficients (the other half of
        the samples), ``G`` gets the symmetrised cross product ½(AᵀB + BᵀA) and ``b`` the mean
        ½(A + B)ᵀy. Since E[AᵀB] = ΓᵀΓ for independent halves, this G has no Monte Carlo noise
        term (E[AᵀA] = ΓᵀΓ + Σ Cov(γ_i), which shrinks the estimates: regression dilution).

        Parameters
        ----------
        coeffs : numpy.ndarray
            ``(n, N, C)`` polynomial coefficients of ``n`` pixels, columns in ``codes`` order.
        observed : numpy.ndarray
            ``(n, C)`` observed radiance of the same pixels.
        mask : numpy.ndarray, optional
            ``(n,)`` bool, pixels to use (default all).
        """
        coeffs = np.asarray(coeffs)
        observed = np.asarray(observed, dtype=np.float64).reshape(coeffs.shape[0], -1)
        n, N_e, C = coeffs.shape
        if N_e != self.n_monomials or C != self.n_channels:
            raise ValueError(f"coeffs shape {coeffs.shape} does not match the system "
                             f"(N_e={self.n_monomials}, C={self.n_channels})")
        if observed.shape[1] != C:
            raise ValueError(f"observed has {observed.shape[1]} channels, expected {C}")
        if mask is not None:
            mask = np.asarray(mask, bool).reshape(n)
            coeffs, observed = coeffs[mask], observed[mask]
        if coeffs_b is not None:
            coeffs_b = np.asarray(coeffs_b)
            if coeffs_b.shape[1:] != coeffs.shape[1:] or (mask is None and len(coeffs_b) != len(coeffs)):
                raise ValueError(f"coeffs_b shape {coeffs_b.shape} does not match coeffs {coeffs.shape}")
            if mask is not None:
                coeffs_b = coeffs_b[mask]
        as_csr = lambda g: [sp.csr_matrix(np.asarray(g[:, :, c], dtype=np.float64)) for c in range(C)]
        return self.accumulate_sparse(as_csr(coeffs), observed, as_csr(coeffs_b) if coeffs_b is not None else None)

    def accumulate_sparse(self, A: list, observed: np.ndarray, B: list | None = None, *,
                          threads: bool = False) -> "GramSystem":
        """:meth:`accumulate` for coefficients given as one sparse ``(n, N)`` matrix per channel
        (``A``, and the independent half ``B``) over this system's ``codes``; ``threads``: the
        channels after the first formed side by side when the first one's product was small
        (:data:`PARALLEL_CHANNEL_BYTES`), for systems formed again and again (the field path's
        robust rounds), not for the pass's, which is formed once beside the render."""
        observed = np.asarray(observed, dtype=np.float64).reshape(A[0].shape[0], -1)

        def channel(c: int) -> tuple:
            y = observed[:, c]
            if B is None:
                return triangle(A[c].T @ A[c]), A[c].T @ y
            AB = A[c].T @ B[c]
            return triangle(0.5 * (AB + AB.T)), 0.5 * (A[c].T @ y + B[c].T @ y)
        def add(c: int, part: tuple) -> None:
            # a system's first block: nothing to add to (a sparse sum costs a pass over both)
            self.G[c] = part[0].tocsr() if self.G[c].nnz == 0 else (self.G[c] + part[0]).tocsr()
            self.b[c] += part[1]
            # a ufunc sum, not a BLAS dot: OpenBLAS's threads spin about 0.1 s after a call and take
            # a core from the next view's kernel (measured: the pass's trace kernel 15 % slower)
            self.yy[c] += float(np.square(observed[:, c]).sum())
        first = channel(0)
        add(0, first)
        # scipy's sparse product runs on one core and releases the GIL: after the first channel,
        # the others side by side when its triangle was small (each product in flight holds its
        # temporaries, and the threads' malloc arenas keep some: a long street's view system is
        # hundreds of MB a channel)
        side_by_side = threads and _bytes(first[0]) <= PARALLEL_CHANNEL_BYTES
        del first
        rest = range(1, self.n_channels)
        if side_by_side:
            for c, part in zip(rest, run_threads([lambda c=c: channel(c) for c in rest])):
                add(c, part)
        else:                           # in turn, each product released once added
            for c in rest:
                add(c, channel(c))
        self.n_pixels += A[0].shape[0]
        return self

    def psd(self, limit: int = PSD_BLOCK_LIMIT) -> "GramSystem":
        """This system with each ``G_c`` projected onto the positive semi-definite matrices
        (negative eigenvalues set to 0), one connected component of ``G_c`` at a time.

        The cross Gram ½(AᵀB + BᵀA) is unbiased but, being a difference of noisy products, not
        PSD: along directions the pixels barely constrain, its negative eigenvalues let the cost
        decrease without bound and the solve runs to the constraints. ΓᵀΓ is PSD, and the
        projection onto that convex set moves the estimate closer to it in Frobenius norm.
        A block-diagonal matrix projects block by block, so splitting G into its connected
        components is exact; a component of more than ``limit`` monomials would need a dense
        eigen-decomposition of its size and is left unprojected (logged, and listed in
        ``psd_skipped``).
        """
        if self.dense is not None:
            dense, skipped = dense_gram.psd(self.dense, limit)
            _log_skipped(skipped, limit)
            return GramSystem(None, self.b.copy(), self.yy.copy(), self.n_pixels, self.codes, tuple(skipped), dense)
        G, skipped, last = [], [], None
        for g in self.G:
            g = g.tocsr()
            if last is None or not _same_pattern(g, last[0]):   # channels share it: one search
                last = g, connected_components(g, directed=False)
            projected, big = _psd_components(g, limit, last[1])
            G.append(projected)
            skipped += big
        _log_skipped(skipped, limit)
        return GramSystem(G, self.b.copy(), self.yy.copy(), self.n_pixels, self.codes, tuple(skipped))

    def _empty_within(self, other: "GramSystem") -> bool:
        """No pixel and no value yet, over monomials ``other`` has (a pass's starting system)."""
        return (self.n_pixels == 0 and not any(g.nnz for g in self.G) and not self.b.any()
                and not self.yy.any() and bool(np.isin(self.codes, other.codes).all()))

    def nbytes(self) -> int:
        """Bytes of the system's arrays (its matrices, dense and those cut, ``b`` and ``yy``)."""
        G = self.G.cut() if self.dense is not None else self.G
        dense = sum(d.nbytes for d in self.dense) if self.dense is not None else 0
        return dense + sum(_bytes(g) for g in G if g is not None) + self.b.nbytes + self.yy.nbytes

    def used_monomials(self) -> np.ndarray:
        """Indices of the monomials some pixel depends on (a non-zero row of G or entry of b, any
        channel). The others do not change the cost: a solver may leave them out."""
        used = np.any(self.b != 0, axis=0)
        if self.dense is not None:
            for d in self.dense:           # symmetric: a non-zero row is a non-zero column
                used |= np.any(d != 0, axis=1)
        else:
            for g in self.G:               # a triangle's entry (m, n) is in row m and column n
                used |= np.diff(g.indptr) > 0
                used[g.indices] = True
        return np.flatnonzero(used)

    def reindexed(self, codes: np.ndarray) -> "GramSystem":
        """This system over the sorted ``codes``, a superset of its own (new monomials: zero).
        The matrices share their values with this system's (only the indices are new)."""
        codes = np.asarray(codes, np.int64)
        if np.array_equal(codes, self.codes):
            if self.dense is not None:     # shared, as the sparse matrices are: never changed in place
                return GramSystem(None, self.b.copy(), self.yy.copy(), self.n_pixels, codes, dense=self.dense)
            return GramSystem(list(self.G), self.b.copy(), self.yy.copy(), self.n_pixels, codes)
        pos = np.searchsorted(codes, self.codes)
        N = len(codes)
        b = np.zeros((self.n_channels, N))
        b[:, pos] = self.b
        if self.dense is not None:
            dense = [np.zeros((N, N)) for _ in self.dense]
            for out, d in zip(dense, self.dense):
                out[np.ix_(pos, pos)] = d
            return GramSystem(None, b, self.yy.copy(), self.n_pixels, codes, dense=dense)
        G = [spread(g, pos, N) for g in self.G]
        return GramSystem(G, b, self.yy.copy(), self.n_pixels, codes)

    def __add__(self, other: "GramSystem") -> "GramSystem":
        if not isinstance(other, GramSystem):
            return NotImplemented
        total = self.reindexed(self.codes)          # new matrix list, values shared until added
        total += other
        return total

    def __iadd__(self, other: "GramSystem") -> "GramSystem":
        """Add ``other`` in place, one channel at a time: each channel's old matrix is released
        as soon as its sum exists, so the peak is both systems plus one channel's sum (the
        views' systems of a 70-material street are 100-600 MB each; a sum that built every
        channel before releasing any needed twice the total)."""
        if not isinstance(other, GramSystem):
            return NotImplemented
        if other.n_channels != self.n_channels:
            raise ValueError(f"cannot add systems of {self.n_channels} and {other.n_channels} channels")
        if self.dense is not None:          # a sum is sparse: the triangles cut, the dense let go
            self.G, self.dense = list(self.G), None
        if self._empty_within(other):            # the sum is ``other``: no sparse sum to build
            self.G, self.b, self.yy = list(other.G), other.b.copy(), other.yy.copy()
            self.n_pixels, self.codes = other.n_pixels, np.asarray(other.codes, np.int64)
            return self
        same = np.array_equal(self.codes, other.codes)
        codes = self.codes if same else np.union1d(self.codes, other.codes)
        N = len(codes)
        mine = None if same else np.searchsorted(codes, self.codes)
        theirs = None if same else np.searchsorted(codes, other.codes)
        for c in range(self.n_channels):
            a = self.G[c] if same else spread(self.G[c], mine, N)
            self.G[c] = None                      # release before the sum is built
            self.G[c] = (a + (other.G[c] if same else spread(other.G[c], theirs, N))).tocsr()
            del a
        if same:
            self.b = self.b + other.b
        else:
            b = np.zeros((self.n_channels, N))
            b[:, mine] = self.b
            b[:, theirs] += other.b
            self.b = b
        self.yy = self.yy + other.yy
        self.n_pixels += other.n_pixels
        self.codes = np.asarray(codes, np.int64)
        return self

    def cost(self, mu: np.ndarray) -> np.ndarray:
        """Per-channel sum of squared residuals ``μ_cᵀ G_c μ_c - 2 b_cᵀ μ_c + yy_c``.

        Parameters
        ----------
        mu : numpy.ndarray
            ``(C, N)`` monomial values per channel (``basis.evaluate(ρ[:, c])``).

        Returns
        -------
        numpy.ndarray
            ``(C,)`` costs (sum them for the total, eq. 6 squared with p = 2).
        """
        mu = np.asarray(mu, dtype=np.float64).reshape(self.n_channels, self.n_monomials)
        if self.dense is not None:
            quad = np.array([m @ (d @ m) for d, m in zip(self.dense, mu)])
        else:
            quad = np.array([2.0 * (m @ (g @ m)) - g.diagonal() @ (m * m) for g, m in zip(self.G, mu)])
        return quad - 2 * np.einsum("ci,ci->c", self.b, mu) + self.yy


def _same_pattern(a: sp.csr_matrix, b: sp.csr_matrix) -> bool:
    """Whether two CSR matrices store entries at the same places (the channels of one pass do:
    their connected components are then the same, a search of 0.35 s each on a 296-weight street)."""
    return a.shape == b.shape and np.array_equal(a.indptr, b.indptr) and np.array_equal(a.indices, b.indices)


def _psd_components(g: sp.csr_matrix, limit: int, components: tuple | None = None
                    ) -> tuple[sp.csr_matrix, list[int]]:
    """``g`` (an upper triangle) with each connected component of at most ``limit`` monomials
    replaced by (the triangle of) its PSD projection (dense eigh of the component), and the sizes
    of the larger ones. ``components``: scipy's ``connected_components(g, directed=False)`` when the
    caller has it."""
    g = g.tocsr()
    n_comp, labels = connected_components(g, directed=False) if components is None else components
    sizes = np.bincount(labels, minlength=n_comp)
    single = np.flatnonzero(sizes[labels] == 1)                   # 1 x 1: max(g_ii, 0)
    if not np.any((sizes > 1) & (sizes <= limit)):   # nothing to project: only the 1 x 1 ones
        negative = single[g.diagonal()[single] < 0.0]
        if len(negative) == 0:                           # g itself: no copy of a large G
            return g, [int(n) for n in sizes[sizes > 1]]
        fix = sp.csr_matrix((-g.diagonal()[negative], (negative, negative)), shape=g.shape)
        out = g + fix
        out.eliminate_zeros()
        return out, [int(n) for n in sizes[sizes > 1]]
    big = np.flatnonzero(sizes > 1)
    if len(big) == 1 and sizes[big[0]] <= limit:     # one component and 1 x 1 ones: no merge of parts
        return _one_component(g, np.flatnonzero(labels == big[0]), single), []
    rows, cols, vals, skipped = [], [], [], []
    kept = np.zeros(g.shape[0], bool)                             # rows of unprojected components
    order = np.argsort(labels, kind="stable")                  # each component: a contiguous run
    bounds = np.concatenate([[0], np.cumsum(sizes)])
    for k in np.flatnonzero(sizes > 1):
        idx = order[bounds[k]:bounds[k + 1]]           # increasing: the argsort is stable
        if len(idx) > limit:                                      # kept sparse, never densified
            skipped.append(len(idx))
            kept[idx] = True
            continue
        block = np.triu(psd_projection(dense_symmetric(principal(g, idx))))
        r, c = np.nonzero(block)
        rows.append(idx[r]), cols.append(idx[c]), vals.append(block[r, c])
    coo = g.tocoo()
    on = kept[coo.row]
    rows.append(coo.row[on]), cols.append(coo.col[on]), vals.append(coo.data[on])
    d = np.maximum(g.diagonal()[single], 0.0)
    rows.append(single), cols.append(single), vals.append(d)
    out = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=g.shape)
    out.eliminate_zeros()
    return out, skipped


def _one_component(g: sp.csr_matrix, idx: np.ndarray, single: np.ndarray) -> sp.csr_matrix:
    """:func:`_psd_components` of a ``g`` with one component of more than one monomial (``idx``,
    increasing) and 1 x 1 ones (``single``): the component's triangle made from its dense
    projection row by row and moved into place, no sort of its entries (the general path's COO
    assembly took 0.25 of a survey fit's 0.8 s around its eigen-decompositions, 2026-12-05)."""
    out = spread(dense_triangle(psd_projection(dense_symmetric(principal(g, idx)))), idx, g.shape[0])
    d = np.maximum(g.diagonal()[single], 0.0)
    if not d.any():
        return out
    out = (out + sp.csr_matrix((d, (single, single)), shape=g.shape)).tocsr()
    out.eliminate_zeros()
    return out


def _log_skipped(skipped: list, limit: int) -> None:
    if skipped:
        log.warning("PSD projection skipped for %d component(s) of G with %s monomials (limit %d)",
                    len(skipped), sorted(set(skipped)), limit)


def _bytes(g: sp.csr_matrix) -> int:
    """Bytes of a CSR matrix's arrays."""
    return g.data.nbytes + g.indices.nbytes + g.indptr.nbytes
