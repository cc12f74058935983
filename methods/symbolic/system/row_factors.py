"""Coefficients expanded by per-pixel factors, and their Gram matrix formed before the expansion.

A lens to estimate multiplies each pixel's coefficients by ``T`` terms
(:func:`~methods.symbolic.survey.vignetting.with_factors`): copy ``t`` of each monomial, the
monomial times parameter ``j_t`` (none for the first), gets the coefficients times ``s_t``, the
pixel's term. A pixel of ``k`` monomials then has ``T k`` and adds ``(T k)²`` pairs to a Gram
product. The block of ``G`` between copies ``t`` and ``u`` is ``Γᵀ diag(w s_t s_u) Γ``; when the
products of the terms are combinations of few functions of the pixel, ``s_t s_u = Σ_k α_tuk e_k``
(a falloff polynomial in ``r²`` of degree 3: ten products, seven powers ``r^{2k}``), the ``K``
matrices ``H_k = Γᵀ diag(w e_k) Γ`` give every block, and they add over pixels, row blocks and
views before the expansion: one sparse product of ``K k²`` pairs a pixel instead of ``T² k²``
(7 against 16), and the expansion once for all the views of a lens.

:class:`RowFactors` keeps what this needs (the coefficients before the expansion, their codes,
the appended parameters, the basis ``e`` and ``α``); :func:`add_factored_products` adds one block's
``H_k`` to their sum, :func:`expanded_gram` forms the blocks of ``G`` from it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from methods.symbolic.system.pixel_matrices import expanded_columns, product_into
from methods.symbolic.trace.monomial_codes import appended_codes

#: largest ``|s_t s_u - Σ_k α_tuk e_k|`` accepted, relative to the largest product
PRODUCT_TOLERANCE = 1e-10


@dataclass(frozen=True)
class RowFactors:
    """How a row block's coefficients were expanded (module docstring).

    Attributes
    ----------
    a, b : list
        The coefficients before the expansion (one sparse ``(n, N_b)`` matrix per channel), the
        two half-sample estimates as in :class:`~methods.symbolic.system.coefficients.ViewCoefficients`;
        ``b`` None without halves.
    codes : numpy.ndarray
        ``(N_b,)`` their sorted monomial codes.
    appended : tuple
        ``j_t`` of each term: the parameter its copies are multiplied by (None: none).
    n_params, max_degree : int
        The base and digits of ``codes``.
    basis : numpy.ndarray
        ``(K, n)``: the functions ``e_k`` of the pixel the terms' products are combinations of.
    alpha : numpy.ndarray
        ``(T, T, K)``, symmetric in its first two axes: ``s_t s_u = Σ_k alpha[t, u, k] e_k``.
    """

    a: list
    b: list | None
    codes: np.ndarray
    appended: tuple
    n_params: int
    max_degree: int
    basis: np.ndarray
    alpha: np.ndarray

    @classmethod
    def of(cls, a: list, b: list | None, codes, appended: tuple, n_params: int, max_degree: int,
           scales: np.ndarray, products: tuple[np.ndarray, np.ndarray]) -> "RowFactors":
        """``products = (basis, alpha)`` checked against the terms' ``scales`` ``(T, n)``: a
        product they do not give raises ``ValueError``."""
        basis, alpha = (np.asarray(p, np.float64) for p in products)
        T = len(scales)
        if alpha.shape != (T, T, len(basis)) or basis.shape[1:] != scales.shape[1:]:
            raise ValueError(f"products: alpha {alpha.shape} and basis {basis.shape} do not fit {T} terms "
                             f"of {scales.shape[1]} pixels (alpha (T, T, K), basis (K, n))")
        if not np.array_equal(alpha, alpha.transpose(1, 0, 2)):
            raise ValueError("products: alpha must be symmetric in its first two axes (s_t s_u = s_u s_t)")
        # ufuncs, not a BLAS product: the views are expanded on threads, and OpenBLAS's own threads
        # spin after a call and take a core from the other view (measured: 0.6 s a fit's views)
        err = largest = 0.0
        for t in range(T):
            for u in range(t, T):
                exact = scales[t] * scales[u]
                err = max(err, np.abs((alpha[t, u][:, None] * basis).sum(axis=0) - exact).max(initial=0.0))
                largest = max(largest, np.abs(exact).max(initial=0.0))
        if err > PRODUCT_TOLERANCE * max(1.0, largest):
            raise ValueError(f"products: the terms' products differ from Σ_k alpha e_k by {err:.3g}; give the "
                             "basis and coefficients the terms' products are combinations of")
        return cls(list(a), None if b is None else list(b), np.asarray(codes, np.int64), tuple(appended),
                   int(n_params), int(max_degree), basis, alpha)

    @property
    def lens(self) -> tuple:
        """What blocks must share for their ``H_k`` to add before one expansion: the appended
        parameters, the code base and ``α``."""
        return self.appended, self.n_params, self.max_degree, self.alpha.tobytes()

    def expanded_codes(self, codes: np.ndarray) -> np.ndarray:
        """``(T, len(codes))``: the code of copy ``t`` of each of ``codes`` (base monomials)."""
        return np.stack([appended_codes(codes, j, self.n_params, self.max_degree) for j in self.appended])


def add_factored_products(D: np.ndarray, factors: RowFactors, c: int, weights: np.ndarray | None,
                          codes: np.ndarray) -> None:
    """``D += [H_0ᵀ | H_1ᵀ | ...]`` with ``H_k = Aᵀ diag(w e_k) B`` of channel ``c`` (``B = A``
    without halves) over the sorted base ``codes`` (a superset of the block's): ``D`` is
    ``(U, K U)`` for ``U`` codes, column ``k U + m`` holding ``H_k``'s row ``m``. Formed as
    ``Bᵀ [diag(w e_0) A | ...]``, the orientation in which scipy's kernel writes the rows of ``D``
    in order (:func:`~methods.symbolic.system.pixel_matrices.product_into`); not symmetrised (the
    cross Gram's ½(H + Hᵀ) is taken on the sum, and makes ``Hᵀ`` as good as ``H``)."""
    A = factors.a[c]
    B = A if factors.b is None else factors.b[c]
    K, n = factors.basis.shape
    U, at = len(codes), np.searchsorted(codes, factors.codes)
    scales = factors.basis if weights is None else factors.basis * np.asarray(weights, np.float64).reshape(1, n)
    stacked = expanded_columns(A, scales, np.arange(K)[:, None] * U + at[None, :], K * U)
    B = B.tocsr()
    product_into(D, sp.csr_matrix((B.data, at[B.indices], B.indptr), shape=(B.shape[0], U)).T.tocsr(), stacked)


def expanded_gram(H: np.ndarray, alpha: np.ndarray):
    """The blocks ``(t, u, G_tu)``, ``t <= u``, of the expanded Gram matrix from the summed dense
    ``H`` ``(K, N_b, N_b)`` (symmetrised here, in place): ``G_tu = Σ_k α_tuk ½(H_k + H_kᵀ)``; the
    block ``(u, t)`` is ``G_tuᵀ``. Over the non-zero ``α`` only (25 of 112 for a lens), and
    without BLAS: the channels run on threads of their own, and OpenBLAS's threads under them
    oversubscribe the cores (measured: three channels' products 5.7 s with, 4.7 s without)."""
    H += H.transpose(0, 2, 1)
    H *= 0.5
    T = alpha.shape[0]
    for t in range(T):
        for u in range(t, T):
            ks = np.flatnonzero(alpha[t, u])
            block = np.zeros(H.shape[1:])
            for k in ks:
                block += alpha[t, u, k] * H[k]
            yield t, u, block
