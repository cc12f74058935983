"""The polynomial cost of one channel as a function of ρ, with its exact gradient and Hessian.

Per channel ``c`` the cost of a Gram system (:class:`~methods.symbolic.system.gram.GramSystem`)
is ``ε²_c(ρ) = μ(ρ)ᵀ G_c μ(ρ) - 2 b_cᵀ μ(ρ) + yy_c`` (paper eq. 6 with p = 2), an explicit
polynomial in the kernel weights: its gradient ``2 J(ρ)ᵀ (G_c μ - b_c)`` comes from
:meth:`MonomialBasis.jacobian_t_dot <methods.symbolic.system.basis.MonomialBasis.jacobian_t_dot>`
and its exact Hessian from the sparse Jacobian and the monomials' second derivatives, with no
rendering. The solver minimises it (:mod:`methods.symbolic.fit.solve`); the standard errors
invert its Hessian at the estimate (:mod:`methods.symbolic.uncertainty`).
"""
from __future__ import annotations

import numpy as np

from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.dense_gram import triangle_nnz
from methods.symbolic.system.gram import GramSystem
from methods.symbolic.system.upper_triangle import dense_symmetric, principal, sandwich, symmetric_dot


#: a channel's cost with at most this many used monomials may form its Gauss-Newton matrix
#: ``Jᵀ G J`` from a dense copy of ``G`` (``8 N²`` bytes, 72 MB at the bound), one BLAS product
DENSE_HESSIAN_MONOMIALS = 3000
#: ... when that product's ``N² D`` multiply-adds are at most this many per stored entry of G's
#: triangle (what the sparse product's work follows). Measured 2026-12-05, 2 cores: bundled
#: urban_canyon_survey (N = 2,568, D = 18, 36 per entry) 6.3 ms a Hessian dense against 21 ms
#: sparse, about 650 Hessians a run: 0.053 ns a multiply-add against 6.4 ns an entry, even at
#: about 120; urban_canyon_field at 100 px (N about 2,100-2,200, D = 20, 353 per entry) its
#: solver stage 12.3 s dense against 10.3 s sparse
DENSE_HESSIAN_FLOPS_PER_ENTRY = 120


class ChannelCost:
    """``ε²_c(x)`` and its exact gradient ``2 Jᵀ(G_c μ - b_c)`` for one channel.

    Only the monomials some pixel depends on (:meth:`GramSystem.used_monomials`) enter the
    products, and ``G_c`` is sparse (its upper triangle stored): an evaluation costs O(nnz(G_c)).
    When it has at most :data:`DENSE_HESSIAN_MONOMIALS` used monomials and is full enough for the
    dense product to be the cheaper (:data:`DENSE_HESSIAN_FLOPS_PER_ENTRY`), the residual and the
    Gauss-Newton matrix come from a dense copy of ``G_c`` instead, made once (bundled
    urban_canyon_survey, 2026-12-05: its projected G is full, and ``G μ`` took 1.0 ms so against
    3.2 ms from the triangle, about 340 evaluations a fit).
    """

    def __init__(self, system: GramSystem, basis: MonomialBasis, c: int, used: np.ndarray | None = None):
        self.basis = basis
        self.used = system.used_monomials() if used is None else np.asarray(used)
        self.b = system.b[c][self.used]
        self.yy = float(system.yy[c])
        self._last = None          # (x, r, μ) of the last residual: the Hessian follows the gradient
        self._dense = None         # the whole G_c, dense: made at first use, or the system's own
        if system.dense is not None:
            self._from_dense(system, c)
        else:
            self.G = principal(system.G[c], self.used)
            self.nnz, self.diagonal = self.G.nnz, self.G.diagonal()

    def _from_dense(self, system: GramSystem, c: int) -> None:
        """G_c on the used monomials from a system held dense: that matrix itself (shared, never
        written) where the dense products are the cheaper (:meth:`_dense_copy`), else its triangle."""
        every = len(self.used) == system.n_monomials
        d = system.dense[c] if every else system.dense[c][np.ix_(self.used, self.used)]
        self.nnz = triangle_nnz(d)
        self.diagonal = d.diagonal().copy()
        if self._dense_copy():
            self.G, self._dense = None, d
        else:
            self.G = principal(system.G[c], self.used)

    def _residual(self, x: np.ndarray) -> np.ndarray:
        """``(size,)`` residual ``G_c μ - b_c`` on the used monomials, 0 elsewhere, and ``μ_used``."""
        if self._last is not None and np.array_equal(self._last[0], x):
            return self._last[1], self._last[2]
        m = self.basis.evaluate(x)[self.used]
        r = np.zeros(self.basis.size)
        Gm = self._dense_matrix() @ m if self._dense_copy() else symmetric_dot(self.G, m, self.diagonal)
        r[self.used] = Gm - self.b
        self._last = (np.array(x, dtype=float, copy=True), r, m)
        return r, m

    def __call__(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        r, m = self._residual(x)
        f = float(m @ (r[self.used] + self.b) - 2.0 * self.b @ m + self.yy)
        return f, 2.0 * self.basis.jacobian_t_dot(x, r)

    def gauss_newton(self, x: np.ndarray) -> np.ndarray:
        """``(D, D)`` Gauss-Newton part ``2 Jᵀ G_c J`` of the Hessian (PSD when ``G_c`` is): with
        the sparse Jacobian from G's triangle (:func:`~methods.symbolic.system.upper_triangle.sandwich`),
        or from a dense copy of G where that is the cheaper (:meth:`_dense_copy`)."""
        J = self.basis.jacobian_sparse(x)[self.used]
        if not self._dense_copy():
            return 2.0 * sandwich(self.G, J, self.diagonal).toarray()
        J = J.toarray()
        return 2.0 * J.T @ (self._dense_matrix() @ J)

    def _dense_matrix(self) -> np.ndarray:
        """The whole ``G_c`` on the used monomials, dense, made once."""
        if self._dense is None:
            self._dense = dense_symmetric(self.G)
        return self._dense

    def _dense_copy(self) -> bool:
        """Whether the residual and the Gauss-Newton matrix use a dense copy of G (class docstring)."""
        N = len(self.used)
        return N <= DENSE_HESSIAN_MONOMIALS and \
            N * N * self.basis.n_params <= DENSE_HESSIAN_FLOPS_PER_ENTRY * max(self.nnz, 1)

    def _residual_curvature(self, x: np.ndarray) -> np.ndarray:
        """``(D, D)`` second-order part ``2 Σ_m (G_c μ - b_c)_m ∇²μ_m`` of the Hessian
        (:meth:`MonomialBasis.hessian_dot`)."""
        return 2.0 * self.basis.hessian_dot(x, self._residual(x)[0])

    def hessian(self, x: np.ndarray) -> np.ndarray:
        """``(D, D)`` exact Hessian ``2 Jᵀ G_c J + 2 Σ_m (G_c μ - b_c)_m ∇²μ_m``."""
        return self.gauss_newton(x) + self._residual_curvature(x)

    def metric(self, x: np.ndarray) -> np.ndarray:
        """Curvature for :func:`framework.optim.minimize`'s ``metric``: the exact Hessian at ``x``
        when it is positive definite, else its Gauss-Newton part."""
        gn = self.gauss_newton(x)
        H = gn + self._residual_curvature(x)
        return H if np.linalg.eigvalsh(H)[0] > 0.0 else gn


def channel_cost_grad(system: GramSystem, basis: MonomialBasis, c: int, x: np.ndarray):
    """Cost ``ε²_c(x)`` and its exact gradient (one-off :class:`ChannelCost`)."""
    return ChannelCost(system, basis, c)(x)


def hessian(system: GramSystem, basis: MonomialBasis, rho: np.ndarray, known: list | None = None) -> np.ndarray:
    """Exact Hessian of the per-channel cost, ``(C, D, D)`` (:meth:`ChannelCost.hessian`).

    ``rho``: ``(D, C)``, or ``(D,)`` for every channel. ``known``: per channel the Hessian at
    ``rho`` already computed (a solve's last), or None; only the others are computed.
    """
    rho = np.asarray(rho, dtype=float).reshape(basis.n_params, -1)
    C = system.n_channels
    rho = np.broadcast_to(rho, (basis.n_params, C))
    known = [None] * C if known is None or len(known) == 0 else list(known)
    if len(known) != C:
        raise ValueError(f"hessian: known has {len(known)} entries for {C} channels")
    used = system.used_monomials() if any(h is None for h in known) else None
    return np.stack([ChannelCost(system, basis, c, used).hessian(rho[:, c]) if h is None else np.asarray(h)
                     for c, h in enumerate(known)])
