"""Which kernel weights the pixels determine at all, and the Gram system restricted to them.

Parameter ``ρ_j`` is *unobservable* when no pixel's polynomial depends on it: every monomial
containing ``ρ_j`` has a zero coefficient in every pixel, i.e. ``G_mm = Σ_i γ_im² = 0`` for every
such monomial ``m`` (tested against a relative tolerance ``rtol`` times the largest diagonal entry
of ``G``, all channels together; :func:`observable_parameters`). The cost is then exactly
independent of ``ρ_j``; the solve runs on the observable parameters only (:func:`restrict_system`,
exact, because the dropped monomials have zero rows and columns in ``G`` and zero entries in
``b``), and an unobservable parameter is reported with NaN estimate and std.
"""
from __future__ import annotations

import numpy as np

from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.gram import GramSystem
from methods.symbolic.system.upper_triangle import principal

#: relative tolerance of the observability test on diag(G)
OBSERVABLE_RTOL = 1e-12


def observable_parameters(system: GramSystem, basis: MonomialBasis, *, rtol: float = OBSERVABLE_RTOL
                          ) -> np.ndarray:
    """``(D,)`` bool: does some pixel's polynomial depend on ``ρ_j``?

    Parameters
    ----------
    system : GramSystem
        Gram system summed over all views.
    basis : MonomialBasis
        Its monomial basis.
    rtol : float
        ``ρ_j`` is unobservable when ``max_c max_{m ∋ j} G_c[m, m] <= rtol · max(diag G)``.

    Returns
    -------
    numpy.ndarray
        ``(D,)`` bool.
    """
    diag = np.max(system.diagonals(), axis=0)                      # (N,) Σ_i γ_im², worst channel
    scale = float(diag.max()) if diag.size else 0.0
    if scale <= 0.0:
        return np.zeros(basis.n_params, dtype=bool)
    per_param = np.zeros(basis.n_params)                           # max over monomials holding ρ_j
    monomials, params = basis.incidence
    np.maximum.at(per_param, params, diag[monomials])
    return per_param > rtol * scale


def restrict_system(system: GramSystem, basis: MonomialBasis, keep: np.ndarray
                    ) -> tuple[GramSystem, MonomialBasis, np.ndarray]:
    """The Gram system in the monomials of the parameters ``keep`` only.

    Parameters
    ----------
    system, basis
        Full system and its basis (same monomials) in ``D`` parameters.
    keep : numpy.ndarray
        ``(D,)`` bool mask, at least one True.

    Returns
    -------
    (GramSystem, MonomialBasis, numpy.ndarray)
        The restricted system, its basis (``sum(keep)`` parameters renumbered in order, the
        monomials of ``basis`` holding only kept parameters) and the index in ``basis`` of each
        restricted monomial. Exact when the dropped parameters are unobservable (their monomials
        have zero rows/columns in ``G`` and zero ``b``). With every parameter kept, ``system``
        and ``basis`` themselves.
    """
    kept = np.flatnonzero(keep)
    if len(kept) == basis.n_params:
        return system, basis, np.arange(basis.size)
    renumber = np.zeros(basis.n_params + 1, dtype=np.int64)       # digit p + 1 -> new p + 1; 0 stays
    renumber[kept + 1] = np.arange(1, len(kept) + 1)
    idx = np.flatnonzero(np.all((basis.digits == 0) | keep[np.maximum(basis.digits - 1, 0)], axis=1))
    # a monotone renumbering keeps the codes sorted (ordered by degree, then largest parameter)
    codes = (renumber[basis.digits[idx]] * (len(kept) + 1) ** np.arange(basis.max_degree)).sum(axis=1)
    sub = MonomialBasis(len(kept), basis.max_degree, codes)
    b, yy = system.b[:, idx].copy(), system.yy.copy()
    if system.dense is not None:
        rows = np.ix_(idx, idx)
        return GramSystem(None, b, yy, system.n_pixels, sub.codes, dense=[d[rows] for d in system.dense]), sub, idx
    G = [principal(g, idx) for g in system.G]
    return GramSystem(G, b, yy, system.n_pixels, sub.codes), sub, idx
