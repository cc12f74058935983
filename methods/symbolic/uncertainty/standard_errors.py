"""Standard errors and correlations of the kernel weights from the polynomial cost.

Per channel the cost is the explicit polynomial ``ε²_c(ρ) = μᵀG_cμ - 2b_cᵀμ + yy_c``
(:mod:`methods.symbolic.system.gram`), so its exact Hessian at the estimate is available without
any rendering (:func:`methods.symbolic.system.cost.hessian`). The standard errors are of the
observable parameters (:mod:`methods.symbolic.uncertainty.observability`); the sandwich's meat
is :mod:`methods.symbolic.uncertainty.sandwich_meat`'s.

Standard errors: sandwich (default, ``method.std=sandwich``)
    The estimate solves ``g(ρ̂) = 0`` for the gradient ``g = Σ_p s_p`` of the cost, a sum of
    independent per-pixel terms (each pixel has its own samples and its own observation noise),
    so ``ρ̂ - ρ ≈ -H_c⁻¹ g(ρ)`` and ``Cov_c ≈ H_c⁻¹ M_c H_c⁻¹`` with ``M_c = Cov(g)`` estimated
    by ``Σ_p (s_p - s̄)(s_p - s̄)ᵀ`` (:func:`~methods.symbolic.uncertainty.sandwich_meat.score_meat`;
    Huber/White). With the cross Gram,
    ``s_p = Jᵀ[a_p(b_pᵀμ̂ - y_p) + b_p(a_pᵀμ̂ - y_p)]`` from the two independent half-sample
    coefficient estimates ``a_p, b_p``, which the pass keeps (with ``γ_p = (a_p + b_p)/2`` and
    ``d_p = (a_p - b_p)/2`` at even spp: ``s_p = 2Jᵀ(γ_p r_p - d_p d_pᵀμ̂)``, ``r_p = γ_pᵀμ̂ - y_p``).
    ``M`` thus holds the image noise, the coefficients' Monte Carlo noise (to first order through
    ``r_p``, whose variance is ``σ²_img + Var_MC(γ_pᵀμ̂)``, and to second order through the
    products of the halves' noises, which dominate along the ill-posed directions where
    ``Jᵀγ_p`` is small) and the per-pixel misfit of the model that the estimate does not
    absorb. Measured on the tiny two-segment scene (tests/methods/test_std_calibration.py, 20 seeds,
    z = (ρ̂ - ρ_ref)/std): RMS z 0.95, |z| < 2 for 96 %; the first-order plug-in
    ``M = 4Σ_p Jᵀγ_pγ_pᵀJ (σ²_img + ((a_p - b_p)ᵀμ̂)²/4)`` gave RMS z 1.33 (up to 1.6 for a
    parameter) and 90 %. Without halves (``gram: plain``, spp < 2) ``s_p = 2Jᵀγ_p r_p``: first
    order only. No std holds a bias the estimate absorbs, such as that of observations holding
    more than N_max reflections (urban_canyon's default view: wall ρ_s error 0.059, std 0.006;
    0.011 with ``observe.max_depth = N_max + 1``).

Standard errors: residual only (``method.std=residual``, Gauss-Newton / Laplace approximation)
    With ``n`` pixels (all views), ``D`` observable parameters, the residual variance
    ``σ²_c = ε²_c(ρ̂) / (n - D)`` and the exact Hessian ``H_c`` of ``ε²_c`` at ``ρ̂``,
    ``Cov_c ≈ 2 σ²_c H_c⁻¹`` (``H_c ≈ 2JᵀJ``, so this is ``σ²_c (JᵀJ)⁻¹``): the ``M`` of
    independent, equal pixel noise ``σ²_c``, the image residual only. It ignores the Monte
    Carlo noise of the coefficients, which the estimate carries in full (RMS z 18 in
    tests/methods/test_std_calibration.py), and is 0 where the cross Gram's cost at ``ρ̂`` is <= 0.

Standard errors of the per-segment fit (``method.cost=per_segment``)
    Its estimate solves estimating equations ``U(ρ̂) = 0`` that are no cost's gradient
    (:mod:`methods.symbolic.fit.per_segment`), so the bread is their Jacobian ``J``, not symmetric:
    ``Cov_c = J_c⁺ M_c J_c⁺ᵀ`` (:func:`estimating_uncertainty`, pseudo-inverse by SVD), with
    ``M_c`` from each pixel's score restricted to the parameters owning the pixel
    (:func:`~methods.symbolic.uncertainty.sandwich_meat.score_meat` with ``owned``). Measured on the tiny
    diffuse scene, seeds 0-7: RMS z
    0.84, |z| < 2 for 96 % (tests/methods/test_per_segment.py).

Both formulas
    ``H_c`` is the exact Hessian of the (PSD-projected) cost at ``ρ̂``, symmetrised and
    inverted through its eigen-decomposition: eigenvalues ``<= rcond · λ_max`` (near-singular
    directions, including negative ones) are dropped (pseudo-inverse). A parameter whose squared
    loading on the dropped directions exceeds ``null_tol`` is not determined to first order; its
    ``std`` is NaN rather than the pseudo-inverse's underestimate. The approximation ignores the
    bound and Σρ <= 1 constraints: where a constraint is active the true uncertainty is one-sided
    and smaller. A parameter whose std exceeds :data:`ILL_DETERMINED_STD` is reported
    ill-determined (:func:`ill_determined`).

Correlation
    ``corr_c = Cov_c / (std_c std_cᵀ)`` per channel; the reported matrix is the mean over
    channels of the per-channel correlations (entries NaN in a channel are left out of the mean).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.cost import hessian
from methods.symbolic.system.gram import GramSystem

#: eigenvalues of H below RCOND * max eigenvalue are treated as zero
RCOND = 1e-10
#: squared loading on dropped directions above which a std is reported NaN
NULL_TOL = 1e-2
#: std above which a parameter is reported ill-determined
ILL_DETERMINED_STD = 0.05

@dataclass
class Uncertainty:
    """Standard errors and correlations of the observable parameters.

    Attributes
    ----------
    std : numpy.ndarray
        ``(D, C)`` standard errors (NaN where not determined to first order).
    covariance : numpy.ndarray
        ``(C, D, D)`` covariance ``H_c⁺ M_c H_c⁺`` (sandwich) or ``2σ²_c H_c⁺`` (residual).
    correlation : numpy.ndarray
        ``(C, D, D)`` per-channel correlation matrices.
    sigma2 : numpy.ndarray
        ``(C,)`` residual variance ``ε²_c / (n - D)``.
    dropped : numpy.ndarray
        ``(C,)`` number of near-singular directions dropped per channel.
    """

    std: np.ndarray
    covariance: np.ndarray
    correlation: np.ndarray
    sigma2: np.ndarray
    dropped: np.ndarray

    @property
    def mean_correlation(self) -> np.ndarray:
        """``(D, D)`` mean over channels of the per-channel correlations (NaN-aware)."""
        corr = self.correlation
        ok = np.isfinite(corr)
        n = ok.sum(axis=0)
        total = np.where(ok, corr, 0.0).sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(n > 0, total / np.maximum(n, 1), np.nan)




def parameter_uncertainty(system: GramSystem, basis: MonomialBasis, rho: np.ndarray, *,
                          meat: np.ndarray | None = None, hessians: list | None = None, rcond: float = RCOND,
                          null_tol: float = NULL_TOL) -> Uncertainty:
    """Standard errors at the estimate ``rho``: ``sqrt(diag(H_c⁺ M_c H_c⁺))`` with the sandwich
    ``meat`` (:func:`~methods.symbolic.uncertainty.sandwich_meat.score_meat`), or
    ``sqrt(diag(2σ²_c H_c⁺))`` without it.

    Parameters
    ----------
    system : GramSystem
        Gram system of the observable parameters
        (:func:`~methods.symbolic.uncertainty.observability.restrict_system`).
    basis : MonomialBasis
        Its basis (``D`` parameters).
    rho : numpy.ndarray
        ``(D, C)`` estimate.
    meat : numpy.ndarray, optional
        ``(C, D, D)`` covariance of the cost's gradient
        (:func:`~methods.symbolic.uncertainty.sandwich_meat.score_meat`); None: the
        residual-only formula.
    hessians : list, optional
        Per channel the exact Hessian at ``rho`` where the solve already computed it there, or
        within a negligible last step of it
        (:attr:`~methods.symbolic.fit.solve.SolveResult.hessians`), or None; the others are
        computed (a 296-weight street: 0.45 s each).
    rcond, null_tol : float
        Eigenvalue threshold of the pseudo-inverse, and the loading on dropped directions
        above which a parameter's std is NaN (see the module docstring).

    Returns
    -------
    Uncertainty
    """
    rho = np.asarray(rho, dtype=float).reshape(basis.n_params, -1)
    C, D = system.n_channels, basis.n_params
    H = hessian(system, basis, rho, known=hessians)
    mu = np.stack([basis.evaluate(rho[:, c]) for c in range(C)])
    dof = max(system.n_pixels - D, 1)
    sigma2 = np.maximum(system.cost(mu), 0.0) / dof
    cov = np.empty((C, D, D))
    std = np.empty((D, C))
    dropped = np.zeros(C, dtype=int)
    for c in range(C):
        Hinv, null_load, dropped[c] = _pseudo_inverse(H[c], rcond)
        cov[c] = 2.0 * sigma2[c] * Hinv if meat is None else Hinv @ meat[c] @ Hinv
        s = np.sqrt(np.maximum(np.diag(cov[c]), 0.0))
        std[:, c] = np.where(null_load > null_tol, np.nan, s)
    corr = _correlation(cov, std)
    return Uncertainty(std=std, covariance=cov, correlation=corr, sigma2=sigma2, dropped=dropped)


def estimating_uncertainty(bread: np.ndarray, meat: np.ndarray, sigma2: np.ndarray, *, rcond: float = RCOND,
                           null_tol: float = NULL_TOL) -> Uncertainty:
    """Standard errors of estimating equations ``U(ρ̂) = 0``: ``sqrt(diag(J_c⁺ M_c J_c⁺ᵀ))``.

    Parameters
    ----------
    bread : numpy.ndarray
        ``(C, D, D)`` Jacobian ``J_c = ∂U/∂ρ`` at the estimate (not symmetric in general).
    meat : numpy.ndarray
        ``(C, D, D)`` covariance of ``U`` (:func:`~methods.symbolic.uncertainty.sandwich_meat.score_meat`
        with ``owned``).
    sigma2 : numpy.ndarray
        ``(C,)`` residual variance, reported as is.
    rcond, null_tol : float
        As in :func:`parameter_uncertainty`: singular values ``<= rcond · σ_max`` are dropped,
        and a parameter loading more than ``null_tol`` on their right singular vectors gets a
        NaN std.

    Returns
    -------
    Uncertainty
    """
    C, D = bread.shape[0], bread.shape[1]
    cov, std, dropped = np.empty((C, D, D)), np.empty((D, C)), np.zeros(C, dtype=int)
    for c in range(C):
        U, w, Vt = np.linalg.svd(bread[c])
        good = w > rcond * w.max() if w.size and w.max() > 0 else np.zeros_like(w, dtype=bool)
        Jinv = (Vt[good].T / w[good]) @ U[:, good].T
        cov[c] = Jinv @ meat[c] @ Jinv.T
        null_load = (Vt[~good] ** 2).sum(axis=0)
        dropped[c] = int((~good).sum())
        std[:, c] = np.where(null_load > null_tol, np.nan, np.sqrt(np.maximum(np.diag(cov[c]), 0.0)))
    return Uncertainty(std=std, covariance=cov, correlation=_correlation(cov, std),
                       sigma2=np.asarray(sigma2, dtype=float), dropped=dropped)


def _pseudo_inverse(H: np.ndarray, rcond: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Eigen pseudo-inverse of the symmetrised ``H``, each parameter's loading on the dropped
    directions, and their number."""
    w, V = np.linalg.eigh(0.5 * (H + H.T))
    top = float(w.max()) if w.size else 0.0
    good = w > rcond * top if top > 0 else np.zeros_like(w, dtype=bool)
    Hinv = (V[:, good] / w[good]) @ V[:, good].T
    null_load = (V[:, ~good] ** 2).sum(axis=1)
    return Hinv, null_load, int((~good).sum())


def _correlation(cov: np.ndarray, std: np.ndarray) -> np.ndarray:
    """``(C, D, D)`` correlations; NaN where a std is NaN or zero."""
    s = np.sqrt(np.maximum(np.einsum("cii->ci", cov), 0.0))          # (C, D)
    s = np.where(np.isfinite(std.T) & (s > 0), s, np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / (s[:, :, None] * s[:, None, :])
    return np.clip(corr, -1.0, 1.0)


def ill_determined(std: np.ndarray, observable: np.ndarray, *, threshold: float = ILL_DETERMINED_STD
                   ) -> np.ndarray:
    """``(P,)`` bool: observable parameters whose std exceeds ``threshold`` in some channel, or is
    NaN there (not determined to first order). Unobservable parameters are False (they have
    their own flag)."""
    std = np.asarray(std, dtype=float).reshape(len(observable), -1)
    with np.errstate(invalid="ignore"):
        loose = np.any(~(std <= threshold), axis=1)             # NaN counts as loose
    return np.asarray(observable, bool) & loose


def correlation_extra(parameters, keep: np.ndarray, unc: Uncertainty | None) -> dict:
    """``extras["correlation"]``: labels ``segment/kernel`` of the observable parameters and the
    channel-mean correlation matrix (JSON-able; NaN entries become None)."""
    kept = [p for p, k in zip(parameters, keep) if k]
    labels = [f"{p.segment_name}/{p.kernel}" for p in kept]
    if unc is None:
        return {"labels": labels, "matrix": [], "averaged_over_channels": True}
    m = unc.mean_correlation
    matrix = [[None if not np.isfinite(x) else float(x) for x in row] for row in m]
    return {"labels": labels, "matrix": matrix, "averaged_over_channels": True}
