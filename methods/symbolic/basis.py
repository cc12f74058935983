"""Monomial basis of the pixel polynomials (paper eq. 7-8).

Every light path ``C`` of at most ``N_max`` reflections carries the radiance
``L(ρ, C) = α ∏_j ρ_j^{e_j}`` with ``Σ_j e_j <= N_max`` (eq. 7), so a pixel is the polynomial
``L_sensor(ρ) = Σ_k γ_k ∏_j ρ_j^{e_{j,k}}`` (eq. 8) in the basis of all monomials of total degree
at most ``N_max`` in ``D = dim(ρ)`` variables. There are ``N_e = C(D + N_max, N_max)`` of them
(paper section 4.3: 286 for D = 10, N_max = 3).
"""
from __future__ import annotations

from itertools import combinations_with_replacement
from math import comb

import numpy as np


class MonomialBasis:
    """All monomials ``∏_j ρ_j^{e_j}`` of total degree ``<= max_degree`` in ``n_params`` variables.

    Monomials are ordered by total degree, then lexicographically by the sorted multiset of
    their variables (``combinations_with_replacement`` order): index 0 is the constant
    monomial, indices ``1..D`` are ``ρ_0 .. ρ_{D-1}``, then the degree-2 monomials, etc.

    Parameters
    ----------
    n_params : int
        ``D = dim(ρ)``, the number of kernel weights (>= 1).
    max_degree : int
        ``N_max``, the maximal total degree (the number of reflections of a path, >= 0).

    Attributes
    ----------
    size : int
        ``N_e = C(D + N_max, N_max)`` (paper section 4.3).
    exponents : numpy.ndarray
        ``(N_e, D)`` int array; row ``m`` holds the exponents ``e_j`` of monomial ``m``.
    key_table : numpy.ndarray
        Flat int32 array of length ``(D + 1)^N_max``. A path that chose parameters
        ``p_0, ..., p_{d-1}`` at its ``d <= N_max`` reflections has the ordered key
        ``Σ_{i<d} (p_i + 1)·(D + 1)^i``; ``key_table[key]`` is the index of the monomial
        ``∏_i ρ_{p_i}``, so the renderer needs no sorting. Entries that are no valid key
        (a zero digit below a non-zero one) hold -1.
    """

    def __init__(self, n_params: int, max_degree: int):
        if int(n_params) < 1:
            raise ValueError(f"n_params={n_params}: must be >= 1")
        if int(max_degree) < 0:
            raise ValueError(f"max_degree={max_degree}: must be >= 0")
        self.n_params = D = int(n_params)
        self.max_degree = N = int(max_degree)
        self.size = comb(D + N, N)

        exps = np.zeros((self.size, D), dtype=np.int64)
        codes = np.zeros(self.size, dtype=np.int64)  # sorted multiset code, base D+1 digits
        m = 0
        for d in range(N + 1):
            combos = list(combinations_with_replacement(range(D), d))
            combos = np.array(combos, dtype=np.int64).reshape(len(combos), d)
            rows = np.arange(m, m + len(combos))
            np.add.at(exps, (np.repeat(rows, d), combos.ravel()), 1)
            codes[rows] = _code(combos, D) if d else 0
            m += len(combos)
        assert m == self.size
        self.exponents = exps
        self.degrees = exps.sum(axis=1)

        # Key table: enumerate ordered tuples depth by depth (vectorised).
        order = np.argsort(codes)
        sorted_codes = codes[order]
        table = np.full((D + 1) ** N if N > 0 else 1, -1, dtype=np.int32)
        table[0] = 0
        for d in range(1, N + 1):
            tuples = np.indices((D,) * d).reshape(d, -1).T          # (D^d, d), digit i = p_i
            weights = (D + 1) ** np.arange(d, dtype=np.int64)
            keys = ((tuples + 1) * weights).sum(axis=1)
            c = _code(np.sort(tuples, axis=1), D)
            pos = np.searchsorted(sorted_codes, c)
            table[keys] = order[pos]
        self.key_table = table

        # Exponent vectors as base-(N_max + 1) numbers, sorted, for :meth:`indices`.
        self._exp_codes = exps @ (N + 1) ** np.arange(D, dtype=np.int64)
        self._exp_order = np.argsort(self._exp_codes)

        # ∂μ_m/∂ρ_k = e_mk · μ_{m - 1_k}: the lowered monomial is in the basis too (degree - 1).
        lowered = np.zeros_like(exps)
        for k in range(D):
            has = exps[:, k] > 0
            lowered[has, k] = self.indices(exps[has] - np.eye(D, dtype=np.int64)[k])
        self._lowered = lowered

        # μ_m = μ_parent(m) · ρ_var(m) (var: the first variable of m): one product per monomial,
        # degree by degree (monomials are ordered by degree, so each degree is a slice).
        self._var = np.argmax(exps > 0, axis=1)
        self._parent = lowered[np.arange(self.size), self._var]
        bounds = np.searchsorted(self.degrees, np.arange(N + 2))
        self._levels = [slice(int(bounds[d]), int(bounds[d + 1])) for d in range(1, N + 1)]
        # Non-zeros of the Jacobian: (monomial, variable, exponent, lowered monomial).
        jm, jk = np.nonzero(exps)
        self._jac = (jm, jk, exps[jm, jk].astype(float), lowered[jm, jk])

    # ------------------------------------------------------------------------------------------
    def key(self, params) -> int:
        """Ordered key ``Σ_i (p_i + 1)(D + 1)^i`` of the parameter sequence ``params``."""
        return int(sum((int(p) + 1) * (self.n_params + 1) ** i for i, p in enumerate(params)))

    def index(self, params) -> int:
        """Monomial index of the multiset ``params`` (any order)."""
        return int(self.key_table[self.key(sorted(params))])

    def indices(self, exponents: np.ndarray) -> np.ndarray:
        """Monomial indices of the rows of ``exponents`` (``(K, D)`` non-negative ints, each row of
        total degree ``<= N_max``)."""
        exponents = np.asarray(exponents, dtype=np.int64).reshape(-1, self.n_params)
        codes = exponents @ (self.max_degree + 1) ** np.arange(self.n_params, dtype=np.int64)
        sorted_codes = self._exp_codes[self._exp_order]
        pos = np.minimum(np.searchsorted(sorted_codes, codes), self.size - 1)
        if exponents.size and (np.any(exponents < 0) or np.any(sorted_codes[pos] != codes)):
            raise ValueError("exponents: a row is not a monomial of this basis (negative, or degree > N_max)")
        return self._exp_order[pos]

    def evaluate(self, rho: np.ndarray) -> np.ndarray:
        """Values of all monomials at ``rho``.

        Parameters
        ----------
        rho : numpy.ndarray
            ``(D,)`` or batched ``(B, D)`` parameter values.

        Returns
        -------
        numpy.ndarray
            ``(N_e,)`` (or ``(B, N_e)``): ``∏_j ρ_j^{e_{j,m}}`` for every monomial ``m`` (eq. 7).
        """
        rho = np.asarray(rho, dtype=float)
        mu = np.empty(rho.shape[:-1] + (self.size,))
        mu[..., 0] = 1.0
        for level in self._levels:
            mu[..., level] = mu[..., self._parent[level]] * rho[..., self._var[level]]
        return mu

    def jacobian(self, rho: np.ndarray, mu: np.ndarray | None = None) -> np.ndarray:
        """Derivatives ``∂(∏_j ρ_j^{e_{j,m}})/∂ρ_k``.

        Parameters
        ----------
        rho : numpy.ndarray
            ``(D,)`` parameter values.
        mu : numpy.ndarray, optional
            ``evaluate(rho)``, if already computed.

        Returns
        -------
        numpy.ndarray
            ``(N_e, D)`` Jacobian ``e_mk μ_{m - 1_k}``; exact, also at ``ρ_k = 0``.
        """
        mu = self.evaluate(rho) if mu is None else mu
        jm, jk, je, jl = self._jac
        J = np.zeros((self.size, self.n_params))
        J[jm, jk] = je * mu[jl]
        return J

    def jacobian_t_dot(self, mu: np.ndarray, r: np.ndarray) -> np.ndarray:
        """``J(ρ)ᵀ r`` without forming ``J`` (it has at most ``N_max`` non-zeros per row).

        Parameters
        ----------
        mu : numpy.ndarray
            ``(N_e,)`` monomials at ρ (:meth:`evaluate`).
        r : numpy.ndarray
            ``(N_e,)`` vector, e.g. the residual ``Gμ - b`` of the cost.

        Returns
        -------
        numpy.ndarray
            ``(D,)``: ``Σ_m e_mk μ_{m - 1_k} r_m`` for every ``k``.
        """
        jm, jk, je, jl = self._jac
        return np.bincount(jk, weights=je * mu[jl] * r[jm], minlength=self.n_params)

    def hessian(self, rho: np.ndarray) -> np.ndarray:
        """Second derivatives ``∂²(∏_j ρ_j^{e_{j,m}})/∂ρ_k∂ρ_l``, shape ``(N_e, D, D)``.

        Lowering twice: ``∂²μ_m/∂ρ_k∂ρ_l = e_mk · e_{m', l} · μ_{m' - 1_l}`` with ``m' = m - 1_k``.
        """
        mu = self.evaluate(rho)
        jm, jk, je, jl = self._jac
        E = self.exponents
        out = np.zeros((self.size, self.n_params, self.n_params))
        coef = je[:, None] * E[jl]                                  # (nnz, D): e_mk · e_{m', l}
        out[jm, jk, :] = coef * mu[self._lowered[jl]]
        return out

    def __repr__(self) -> str:
        return f"MonomialBasis(n_params={self.n_params}, max_degree={self.max_degree}, size={self.size})"


def _code(sorted_tuples: np.ndarray, D: int) -> np.ndarray:
    """Integer code of sorted multisets (rows), base ``D + 1`` digits ``p + 1``."""
    d = sorted_tuples.shape[1]
    return ((sorted_tuples + 1) * (D + 1) ** np.arange(d, dtype=np.int64)).sum(axis=1)
