"""Observability and standard errors of the kernel weights from the polynomial cost.

Per channel the cost is the explicit polynomial ``ε²_c(ρ) = μᵀG_cμ - 2b_cᵀμ + yy_c``
(:mod:`methods.symbolic.system.gram`), so its exact Hessian at the estimate is available without any
rendering (:func:`methods.symbolic.system.cost.hessian`).

Observability
    Parameter ``ρ_j`` is *unobservable* when no pixel's polynomial depends on it: every monomial
    containing ``ρ_j`` has a zero coefficient in every pixel, i.e. ``G_mm = Σ_i γ_im² = 0`` for
    every such monomial ``m`` (tested against a relative tolerance ``rtol`` times the largest
    diagonal entry of ``G``, all channels together). The cost is then exactly independent of
    ``ρ_j``; the solve runs on the observable parameters only (:func:`restrict_system`, exact,
    because the dropped monomials have zero rows and columns in ``G`` and zero entries in ``b``).

Standard errors: sandwich (default, ``method.std=sandwich``)
    The estimate solves ``g(ρ̂) = 0`` for the gradient ``g = Σ_p s_p`` of the cost, a sum of
    independent per-pixel terms (each pixel has its own samples and its own observation noise),
    so ``ρ̂ - ρ ≈ -H_c⁻¹ g(ρ)`` and ``Cov_c ≈ H_c⁻¹ M_c H_c⁻¹`` with ``M_c = Cov(g)`` estimated
    by ``Σ_p (s_p - s̄)(s_p - s̄)ᵀ`` (:func:`score_meat`; Huber/White). With the cross Gram,
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
    (:func:`score_meat` with ``owned``). Measured on the tiny diffuse scene, seeds 0-7: RMS z
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
import scipy.sparse as sp

from framework.threads import run_threads
from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.misfit.clusters import cr1_factor
from methods.symbolic.system.gram import GramSystem
from methods.symbolic.system.upper_triangle import principal
from methods.symbolic.system.view_systems import row_blocks
from methods.symbolic.system.cost import hessian

#: relative tolerance of the observability test on diag(G)
OBSERVABLE_RTOL = 1e-12
#: eigenvalues of H below RCOND * max eigenvalue are treated as zero
RCOND = 1e-10
#: squared loading on dropped directions above which a std is reported NaN
NULL_TOL = 1e-2
#: std above which a parameter is reported ill-determined
ILL_DETERMINED_STD = 0.05
#: stored coefficients (both halves, one channel) of the rows :func:`score_meat` scores at once,
#: so that its sparse temporaries (the coefficients times J, the scores) stay bounded whatever the
#: pass's tile. Measured on a 1920x1080 view (bench section 1b, 48 tiles): scored a whole tile at
#: a time on two threads the run peaked at 1,345 MiB, on one thread 854 MiB, in chunks on two
#: threads 841 MiB
SCORE_CHUNK_NNZ = 1 << 20


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
    diag = np.max([g.diagonal() for g in system.G], axis=0)       # (N,) Σ_i γ_im², worst channel
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
    G = [principal(g, idx) for g in system.G]
    return GramSystem(G, system.b[:, idx].copy(), system.yy.copy(), system.n_pixels, sub.codes), sub, idx


def score_meat(basis: MonomialBasis, rho: np.ndarray, views, columns: np.ndarray, codes: np.ndarray, *,
               owned: list | None = None, clusters: list | None = None, poses=None) -> np.ndarray:
    """``(C, D, D)`` sandwich meat ``M_c = Σ_p (s_p - s̄)(s_p - s̄)ᵀ`` over every pixel of every view.

    ``s_p`` is pixel ``p``'s term of the gradient of the (cross-Gram) cost at ``rho``:
    ``s_p = Jᵀ[a_p (b_pᵀμ - y_p) + b_p (a_pᵀμ - y_p)]`` with the half-sample coefficients
    ``a_p``, ``b_p`` (at even spp, with ``γ_p = (a_p + b_p)/2``, ``d_p = (a_p - b_p)/2`` and
    ``r_p = γ_pᵀμ - y_p``: ``s_p = 2Jᵀ(γ_p r_p - d_p d_pᵀμ)``). Without halves (``b`` None)
    ``s_p = 2Jᵀa_p r_p``. ``s̄`` is their mean (0 at an interior
    minimum of the unprojected cost). With ``clusters`` the scores are summed within each cluster
    first (the cluster-robust meat, :mod:`methods.symbolic.misfit.clusters`, with its CR1 correction).
    With ``poses`` each view's camera is uncertain too (``method.align``): an error ``δ`` of its
    pose moves pixel ``p``'s residual by ``G_p δ``, so the view's summed scores by ``T δ`` with
    ``T = Σ_p ∂s_p/∂r_p G_p``; ``T Σ Tᵀ`` (``Σ`` the pose's covariance) is added to the meat
    (the delta method; the pose error independent of the pixels' noise in this pass).

    Parameters
    ----------
    basis : MonomialBasis
        Basis of the observable parameters (``D``).
    rho : numpy.ndarray
        ``(D, C)`` estimate.
    views : iterable
        ``(coefficients, y[, weights])`` per view (``weights``: ``(n,)`` pixel weights of the
        cost, or None for all 1): the coefficients as row blocks (``n_rows`` and ``blocks()``
        giving ``(first row, block)``, a block with ``a``, ``b`` (lists of ``C`` sparse
        matrices, ``b`` possibly None), ``split`` and ``codes`` (the monomial codes of the
        matrices' columns, a subset of ``codes``):
        :class:`~methods.symbolic.system.coefficients.TiledCoefficients` or ``ViewCoefficients``),
        and the ``(n, C)`` observed pixels.
    columns : numpy.ndarray
        Index in ``codes`` of each monomial of ``basis`` (:func:`restrict_system`); the other
        columns are weighted 0.
    codes : numpy.ndarray
        Sorted codes of the system the views were summed into.
    owned : list, optional
        Per view a ``(n, D)`` sparse 0/1 matrix: each pixel's score kept on the parameters that
        own the pixel only (the per-segment fit's estimating equations,
        :mod:`methods.symbolic.fit.per_segment`); None keeps every parameter (the joint cost).
    clusters : list, optional
        Per view the ``(n,)`` cluster id of each pixel (:func:`~methods.symbolic.misfit.clusters.cluster_ids`);
        None: every pixel its own cluster (the pixel sandwich).
    poses : iterable, optional
        Per view, in turn, None (its camera exact) or ``(G, Σ)``: the ``(n, C, k)`` change of each pixel's
        residual per unit of the pose's ``k`` parameters and their ``(k, k)`` covariance
        (:func:`~methods.symbolic.misfit.registration.pose_sensitivity`).

    Returns
    -------
    numpy.ndarray
    """
    rho = np.asarray(rho, dtype=float).reshape(basis.n_params, -1)
    D, C = rho.shape
    mu = np.zeros((C, len(codes)))
    J = []
    for c in range(C):
        mu[c, columns] = basis.evaluate(rho[:, c])
        Jc = basis.jacobian_sparse(rho[:, c]).tocoo()
        J.append(sp.csr_matrix((Jc.data, (columns[Jc.row], Jc.col)), shape=(len(codes), D)))
    outer, total, n, groups = np.zeros((C, D, D)), np.zeros((C, D)), 0, 0
    pose_meat = np.zeros((C, D, D))
    poses = None if poses is None else iter(poses)
    for v, (view, y_view, *weights) in enumerate(views):
        pose = None if poses is None else next(poses)
        T = None if pose is None else np.zeros((C, D, pose[0].shape[2]))
        n += view.n_rows
        start = 0
        ids = None if clusters is None else np.asarray(clusters[v])
        n_groups = view.n_rows if ids is None else int(ids.max()) + 1
        groups += n_groups
        sums = [None] * C           # the view's cluster sums of the scores, per channel
        # a tiled view: one block in memory at a time, scored a chunk of its rows at a time
        for block, y_block, w_block in row_blocks(view, y_view, weights[0] if weights else None):
            for lo, hi in _row_chunks(block):
                y, w_pix = y_block[lo:hi], None if w_block is None else w_block[lo:hi]
                own = None if owned is None else owned[v][start + lo:start + hi]
                rows = None if ids is None else ids[start + lo:start + hi]
                member = None if rows is None else sp.csr_matrix(
                    (np.ones(len(rows)), (rows, np.arange(len(rows)))), shape=(n_groups, len(rows)))
                # the channels on threads: their sparse products release the GIL
                G = None if pose is None else pose[0][start + lo:start + hi]
                tasks = [lambda c=c: _block_terms(*_score(block, (lo, hi), y, w_pix, mu, J, codes, own, c,
                                                         slope=G is not None), member,
                                                  None if G is None else G[:, c])
                         for c in range(C)]
                for c, (total_c, term, slope) in enumerate(run_threads(tasks)):
                    total[c] += total_c
                    if T is not None:
                        T[c] += slope
                    if member is None:
                        outer[c] += term
                    else:
                        sums[c] = term if sums[c] is None else sums[c] + term
            start += block.n_rows
        for c in range(C):
            if sums[c] is not None:
                outer[c] += (sums[c].T @ sums[c]).toarray()
            if T is not None:
                pose_meat[c] += T[c] @ pose[1] @ T[c].T
    meat = outer - np.einsum("ci,cj->cij", total, total) / max(groups, 1)
    return (meat if clusters is None else cr1_factor(groups, n, D) * meat) + pose_meat


def _row_chunks(block) -> list[tuple[int, int]]:
    """``[lo, hi)`` row ranges of a block holding at most about :data:`SCORE_CHUNK_NNZ` stored
    coefficients of one channel each (cut by channel 0's rows; a single row may exceed it)."""
    count = block.a[0].indptr if block.b is None else block.a[0].indptr + block.b[0].indptr
    cuts = np.searchsorted(count, np.arange(SCORE_CHUNK_NNZ, count[-1], SCORE_CHUNK_NNZ), side="right") - 1
    edges = np.unique(np.concatenate([[0], cuts[cuts > 0], [block.n_rows]]))
    return list(zip(edges[:-1].tolist(), edges[1:].tolist()))


def _block_terms(s: sp.csr_matrix, ds: sp.csr_matrix | None, member: sp.csr_matrix | None, G: np.ndarray | None
                 ) -> tuple[np.ndarray, object, np.ndarray | None]:
    """A block's scores ``s`` summed over its pixels, and their outer product ``sᵀs`` (dense) or,
    with the ``(clusters, n)`` 0/1 ``member``, their sums per cluster (sparse); with the pose
    sensitivity ``G`` ``(n, k)`` of its residuals, ``dsᵀG`` ``(D, k)`` (``ds``: ∂s_p/∂r_p)."""
    slope = None if G is None else np.asarray(ds.T @ G)
    return np.asarray(s.sum(axis=0)).ravel(), (s.T @ s).toarray() if member is None else member @ s, slope


def _score(block, rows: tuple[int, int], y, w_pix, mu, J, codes, own, c: int, *, slope: bool = False
           ) -> tuple[sp.csr_matrix, sp.csr_matrix | None]:
    """The ``(n, D)`` sparse scores ``s_p`` in channel ``c`` of a block's ``rows`` ``[lo, hi)``
    and (``slope``) their derivatives ``∂s_p/∂r_p`` by the pixel's residual, else None
    (:func:`score_meat`; the task copies only its own channel's rows)."""
    lo, hi = rows
    cut = (lambda m: m) if (lo, hi) == (0, block.n_rows) else (lambda m: m[lo:hi])   # noqa: E731
    at = np.searchsorted(codes, block.codes)                 # the block's columns in ``codes``
    mu_v, J_v = mu[c, at], J[c][at]
    # sparse scores: a pixel's paths touch a few of the D parameters, so sᵀs costs
    # Σ_p nnz(s_p)² instead of pixels × D² (dense)
    A = cut(block.a[c])
    ra, aJ = A @ mu_v - y[:, c], (A @ J_v).tocsr()
    if block.b is None:
        s = sp.diags(2.0 * ra) @ aJ
        ds = 2.0 * aJ if slope else None
    else:
        B = cut(block.b[c])
        rb, bJ = B @ mu_v - y[:, c], (B @ J_v).tocsr()
        s = sp.diags(rb) @ aJ + sp.diags(ra) @ bJ
        ds = aJ + bJ if slope else None
    if w_pix is not None:            # the weighted cost's term: w_p times the unweighted one
        s, ds = sp.diags(w_pix) @ s, None if ds is None else sp.diags(w_pix) @ ds
    if own is not None:              # estimating equations: a pixel scores its owners only
        s, ds = s.multiply(own), None if ds is None else ds.multiply(own)
    return s.tocsr(), None if ds is None else sp.csr_matrix(ds)


def parameter_uncertainty(system: GramSystem, basis: MonomialBasis, rho: np.ndarray, *,
                          meat: np.ndarray | None = None, rcond: float = RCOND,
                          null_tol: float = NULL_TOL) -> Uncertainty:
    """Standard errors at the estimate ``rho``: ``sqrt(diag(H_c⁺ M_c H_c⁺))`` with the sandwich
    ``meat`` (:func:`score_meat`), or ``sqrt(diag(2σ²_c H_c⁺))`` without it.

    Parameters
    ----------
    system : GramSystem
        Gram system of the observable parameters (:func:`restrict_system`).
    basis : MonomialBasis
        Its basis (``D`` parameters).
    rho : numpy.ndarray
        ``(D, C)`` estimate.
    meat : numpy.ndarray, optional
        ``(C, D, D)`` covariance of the cost's gradient (:func:`score_meat`); None: the
        residual-only formula.
    rcond, null_tol : float
        Eigenvalue threshold of the pseudo-inverse, and the loading on dropped directions
        above which a parameter's std is NaN (see the module docstring).

    Returns
    -------
    Uncertainty
    """
    rho = np.asarray(rho, dtype=float).reshape(basis.n_params, -1)
    C, D = system.n_channels, basis.n_params
    H = hessian(system, basis, rho)
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
        ``(C, D, D)`` covariance of ``U`` (:func:`score_meat` with ``owned``).
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
