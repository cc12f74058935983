"""Monomial basis of the pixel polynomials (paper eq. 7-8), restricted to the monomials that occur.

Every light path ``C`` of at most ``N_max`` reflections carries the radiance
``L(ρ, C) = α ∏_j ρ_j^{e_j}`` with ``Σ_j e_j <= N_max`` (eq. 7), so a pixel is the polynomial
``L_sensor(ρ) = Σ_k γ_k ∏_j ρ_j^{e_{j,k}}`` (eq. 8). All monomials of total degree at most
``N_max`` in ``D = dim(ρ)`` variables number ``N_e = C(D + N_max, N_max)`` (paper section 4.3: 286
for D = 10, N_max = 3), but a path touches at most ``N_max`` parameters and which ones is fixed by
the scene's geometry: most of them never occur. So a basis is the sorted list of the monomials that
do, each named by its multiset code (:mod:`methods.symbolic.trace.monomial_codes`).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from methods.symbolic.trace.monomial_codes import all_codes, code_digits, encode_digits, merge_codes


class MonomialBasis:
    """Monomials ``∏_j ρ_j^{e_j}`` of total degree ``<= max_degree`` in ``n_params`` variables: all of
    them, or those of ``codes``.

    Parameters
    ----------
    n_params, max_degree : int
        ``D`` and ``N_max``.
    codes : numpy.ndarray, optional
        Sorted, unique multiset codes (:mod:`~methods.symbolic.trace.monomial_codes`) of the
        monomials; default all (:func:`~methods.symbolic.trace.monomial_codes.all_codes`). Code 0 (the
        constant, emitters seen directly) is always added.

    Attributes
    ----------
    size : int
        Number of monomials (``N_e`` for the full basis).
    codes : numpy.ndarray
        ``(size,)`` int64 sorted codes; monomial ``m`` is ``codes[m]``.
    digits : numpy.ndarray
        ``(size, N_max)`` int64 digits ``p + 1`` of each monomial (0: empty position).
    degrees : numpy.ndarray
        ``(size,)`` total degree of each monomial.
    """

    def __init__(self, n_params: int, max_degree: int, codes: np.ndarray | None = None):
        if int(n_params) < 1:
            raise ValueError(f"n_params={n_params}: must be >= 1")
        if int(max_degree) < 0:
            raise ValueError(f"max_degree={max_degree}: must be >= 0")
        self.n_params = D = int(n_params)
        self.max_degree = N = int(max_degree)
        codes = all_codes(D, N) if codes is None else merge_codes([0], codes)
        if codes.size and codes[-1] >= (D + 1) ** N:
            raise ValueError(f"code {codes[-1]} is no monomial of degree <= {N} in {D} parameters")
        self.codes = codes
        self.size = len(codes)
        self.digits = code_digits(codes, D, N)
        self.degrees = (self.digits > 0).sum(axis=1)
        # Non-zeros of the Jacobian, one per non-empty digit: ∂μ_m/∂ρ_k sums over the positions
        # holding k, so repeated parameters give their exponents.
        self._jm, self._jpos = np.nonzero(self.digits)
        self._jk = self.digits[self._jm, self._jpos] - 1
        self._pair_cache = None          # :meth:`_pair_index`, built on first use
        self._jacobian_cache = None      # :meth:`_other_digits`, built on first use

    @property
    def incidence(self) -> tuple[np.ndarray, np.ndarray]:
        """``(monomials, parameters)``: one pair per non-empty digit (a parameter repeated in a
        monomial appears once per repetition)."""
        return self._jm, self._jk

    @property
    def exponents(self) -> np.ndarray:
        """``(size, D)`` int exponents (dense: for small bases and tests)."""
        E = np.zeros((self.size, self.n_params), dtype=np.int64)
        np.add.at(E, (self._jm, self._jk), 1)
        return E

    # ------------------------------------------------------------------------------------------
    def key(self, params) -> int:
        """Ordered key ``Σ_i (p_i + 1)(D + 1)^i`` of the parameter sequence ``params``."""
        return int(sum((int(p) + 1) * (self.n_params + 1) ** i for i, p in enumerate(params)))

    def index(self, params) -> int:
        """Monomial index of the multiset ``params`` (any order)."""
        return int(self._positions(np.array([self.key(sorted(params))]))[0])

    def indices(self, exponents: np.ndarray) -> np.ndarray:
        """Monomial indices of the rows of ``exponents`` (``(K, D)`` non-negative ints, each row of
        total degree ``<= N_max``)."""
        E = np.asarray(exponents, dtype=np.int64).reshape(-1, self.n_params)
        if np.any(E < 0) or np.any(E.sum(axis=1) > self.max_degree):
            raise ValueError("exponents: a row is not a monomial of this basis (negative, or degree > N_max)")
        digits = np.zeros((len(E), self.max_degree), dtype=np.int64)
        for r, e in enumerate(E):
            ps = np.repeat(np.arange(self.n_params), e) + 1
            digits[r, :len(ps)] = ps
        return self._positions(encode_digits(digits, self.n_params))

    def _positions(self, codes: np.ndarray) -> np.ndarray:
        """Indices of ``codes`` in this basis (ValueError for a code it lacks)."""
        pos = np.minimum(np.searchsorted(self.codes, codes), self.size - 1)
        if np.any(self.codes[pos] != codes):
            raise ValueError("a row is not a monomial of this basis")
        return pos

    def _factors(self, rho: np.ndarray) -> np.ndarray:
        """``(..., size, N_max)`` factor of each digit: ``ρ_{p}`` or 1 for an empty digit."""
        rho = np.asarray(rho, dtype=float)
        padded = np.concatenate([np.ones(rho.shape[:-1] + (1,)), rho], axis=-1)
        return padded[..., self.digits]

    def evaluate(self, rho: np.ndarray) -> np.ndarray:
        """Values ``∏_j ρ_j^{e_{j,m}}`` of all monomials (eq. 7) at ``rho`` (``(D,)`` or batched
        ``(B, D)``): ``(size,)`` or ``(B, size)``."""
        return self._factors(rho).prod(axis=-1)

    def _jacobian_values(self, rho: np.ndarray) -> np.ndarray:
        """Per Jacobian non-zero (monomial, digit position): the product of the monomial's
        other factors (no division: exact also at ``ρ = 0``), gathered from the ``D + 1`` padded
        weights by the cached digits (:meth:`_other_digits`; gathering each monomial's factors
        row by row took 4x longer: 50 ms of a 120 ms evaluation at 296 weights)."""
        return _product_of_factors(rho, self._other_digits(), len(self._jm))

    def _other_digits(self) -> np.ndarray:
        """``(N_max, nnz)`` int32: per Jacobian non-zero, its monomial's digits with its own
        position emptied (0: factor 1), one row per position. Built once per basis."""
        if getattr(self, "_jacobian_cache", None) is None:  # (absent from bases pickled before it)
            own = np.arange(self.max_degree)[None, :] == self._jpos[:, None]
            self._jacobian_cache = np.ascontiguousarray(np.where(own, 0, self.digits[self._jm]).T, dtype=np.int32)
        return self._jacobian_cache

    def jacobian_sparse(self, rho: np.ndarray) -> sp.csr_matrix:
        """``(size, D)`` sparse Jacobian ``∂μ_m/∂ρ_k`` (at most ``N_max`` non-zeros a row)."""
        return sp.csr_matrix((self._jacobian_values(rho), (self._jm, self._jk)), shape=(self.size, self.n_params))

    def jacobian(self, rho: np.ndarray) -> np.ndarray:
        """Dense ``(size, D)`` Jacobian (:meth:`jacobian_sparse`); exact, also at ``ρ_k = 0``."""
        return self.jacobian_sparse(rho).toarray()

    def jacobian_t_dot(self, rho: np.ndarray, r: np.ndarray) -> np.ndarray:
        """``J(ρ)ᵀ r`` (``(D,)``) for a ``(size,)`` vector ``r`` without forming ``J``."""
        return np.bincount(self._jk, weights=self._jacobian_values(rho) * r[self._jm], minlength=self.n_params)

    def _pair_index(self) -> tuple:
        """``(monomial, k, l, others)`` of every non-zero of the monomial Hessians, one per ordered
        pair of distinct non-empty digit positions (summing them gives the exponents' factors);
        ``others``: ``(N_max, n)`` the monomial's digits with the pair's two positions emptied.
        Built once per basis: a Hessian then costs one gather and product (a solve takes tens)."""
        if getattr(self, "_pair_cache", None) is None:      # (absent from bases pickled before it)
            N = self.max_degree
            parts = []
            for j in range(N):
                on = (self.digits[self._jm, j] > 0) & (self._jpos != j)
                m, pos = self._jm[on], self._jpos[on]
                skip = (np.arange(N)[None, :] == pos[:, None]) | (np.arange(N)[None, :] == j)
                parts.append((m, self._jk[on], self.digits[m, j] - 1, np.where(skip, 0, self.digits[m])))
            if not parts:
                parts = [(np.zeros(0, int), np.zeros(0, int), np.zeros(0, int), np.zeros((0, N), int))]
            # int32: half the memory of int64 (about 6 pairs a monomial; 75 MB at 296 weights)
            m, k, l, others = (np.concatenate(a).astype(np.int32) for a in zip(*parts))
            self._pair_cache = (m, k, l, np.ascontiguousarray(others.T))
        return self._pair_cache

    def _pairs(self, rho: np.ndarray) -> tuple:
        """``(monomial, k, l, value)`` of every non-zero of the monomial Hessians at ``rho``
        (:meth:`_pair_index`): the value is the product of the monomial's other factors."""
        m, k, l, others = self._pair_index()
        return m, k, l, _product_of_factors(rho, others, len(m))

    def hessian_dot(self, rho: np.ndarray, r: np.ndarray) -> np.ndarray:
        """``(D, D)``: ``Σ_m r_m ∇²μ_m(ρ)``, the residual part of the cost's Hessian."""
        m, k, l, vals = self._pairs(rho)
        D = self.n_params
        return np.bincount(k.astype(np.int64) * D + l, weights=vals * r[m], minlength=D * D).reshape(D, D)

    def hessian(self, rho: np.ndarray) -> np.ndarray:
        """Dense ``(size, D, D)`` second derivatives (small bases and tests)."""
        m, k, l, vals = self._pairs(rho)
        out = np.zeros((self.size, self.n_params, self.n_params))
        np.add.at(out, (m, k, l), vals)
        return out

    def __repr__(self) -> str:
        return f"MonomialBasis(n_params={self.n_params}, max_degree={self.max_degree}, size={self.size})"


def _product_of_factors(rho: np.ndarray, digits: np.ndarray, n: int) -> np.ndarray:
    """``(n,)`` products ``Π_j ρ_{digits[j] - 1}`` (digit 0: factor 1) over the rows of the
    ``(N_max, n)`` ``digits``: one gather from the ``D + 1`` padded weights a row (contiguous
    gathers; the ``(n, N_max)`` gather and ``prod(axis=1)`` took 4x longer)."""
    padded = np.concatenate([[1.0], np.asarray(rho, dtype=float)])
    out = np.ones(n)
    for row in digits:
        out *= padded[row]
    return out
