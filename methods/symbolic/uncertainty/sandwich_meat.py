"""The meat of the sandwich standard errors: the covariance of the cost's gradient, from each
pixel's score.

The estimate solves ``g(ρ̂) = 0`` for the gradient ``g = Σ_p s_p`` of the cost, a sum of
independent per-pixel terms, so its covariance ``M_c`` is estimated by
``Σ_p (s_p - s̄)(s_p - s̄)ᵀ`` (:func:`score_meat`; the scores summed within clusters first for the
cluster std, :mod:`methods.symbolic.misfit.clusters`; a registered camera's pose uncertainty
added by the delta method). Each view's coefficients are scored one row block, and one chunk of
rows, at a time. :mod:`methods.symbolic.uncertainty.standard_errors` puts ``M_c`` between the
inverted Hessians (or the estimating equations' Jacobians) and says why.
"""
from __future__ import annotations

import functools

import numpy as np
import scipy.sparse as sp

from framework.threads import run_threads, two_at_a_time
from methods.symbolic.misfit.clusters import cr1_factor
from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.device_products import device_products
from methods.symbolic.system.pixel_matrices import dense_jacobian, rows_times, stored_per_row
from methods.symbolic.system.view_systems import row_blocks

#: stored coefficients (both halves, one channel) of the rows :func:`score_meat` scores at once,
#: so that its sparse temporaries (the coefficients times J, the scores) stay bounded whatever the
#: pass's tile. Measured on a 1920x1080 view (bench section 1b, 48 tiles): scored a whole tile at
#: a time on two threads the run peaked at 1,345 MiB, on one thread 854 MiB, in chunks on two
#: threads 841 MiB
SCORE_CHUNK_NNZ = 1 << 20


def score_meat(basis: MonomialBasis, rho: np.ndarray, views, columns: np.ndarray, codes: np.ndarray, *,
               owned: list | None = None, clusters: list | None = None, poses=None, device: bool = False
               ) -> np.ndarray:
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
        Index in ``codes`` of each monomial of ``basis``
        (:func:`~methods.symbolic.uncertainty.observability.restrict_system`); the other
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
    device : bool
        Form the scores' products with the coefficients (``A μ``, ``A J``: a pass over every stored
        coefficient per parameter) on the active Mitsuba variant's device
        (:mod:`methods.symbolic.system.device_products`), the rest (the scores' combination and
        their outer products, ``O(pixels × D²)`` in BLAS) on the host; False: all on the host
        (scipy). The same values on a CPU (the same sums in the same order). Only for at most
        :data:`~methods.symbolic.system.pixel_matrices.DENSE_JACOBIAN_COLUMNS` parameters, whose
        scores are dense; with more the host forms them either way.

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
        view, mu_v, J_v, codes_v = _own_monomials(view, mu, J, codes)
        pose = None if poses is None else next(poses)
        T = None if pose is None else np.zeros((C, D, pose[0].shape[2]))
        n += view.n_rows
        ids = None if clusters is None else np.asarray(clusters[v])
        n_groups = view.n_rows if ids is None else int(ids.max()) + 1
        groups += n_groups
        sums = [None] * C           # the view's cluster sums of the scores, per channel
        # a tiled view: one block in memory at a time (two where a pair of chunks spans two),
        # scored two chunks of its rows at a time, each chunk's channels a task
        for pair in two_at_a_time(_chunks(view, y_view, weights[0] if weights else None)):
            tasks = []
            for block, y_block, w_block, start, (lo, hi) in pair:
                y, w_pix = y_block[lo:hi], None if w_block is None else w_block[lo:hi]
                own = None if owned is None else owned[v][start + lo:start + hi]
                rows = None if ids is None else ids[start + lo:start + hi]
                member = None if rows is None else sp.csr_matrix(
                    (np.ones(len(rows)), (rows, np.arange(len(rows)))), shape=(n_groups, len(rows)))
                G = None if pose is None else pose[0][start + lo:start + hi]
                products = _on_device(block, (lo, hi), mu_v, J_v, codes_v, C) if device else [None] * C
                tasks += [functools.partial(_chunk_terms, block, (lo, hi), y, w_pix, mu_v, J_v, codes_v, own, c,
                                            member, G, products[c]) for c in range(C)]
            # on threads: the sparse products release the GIL. Three channels on two cores leave
            # one idle a third of the time, two chunks' six tasks do not (bundled
            # urban_canyon_survey's first pass, 2026-12-05: its meat 3.3 s a chunk at a time, 2.8 s
            # two at a time). Summed in chunk and channel order, as one chunk at a time
            for k, (total_c, term, slope) in enumerate(run_threads(tasks)):
                c = k % C
                total[c] += total_c
                if T is not None:
                    T[c] += slope
                if ids is None:
                    outer[c] += term
                else:
                    sums[c] = term if sums[c] is None else sums[c] + term
        for c in range(C):
            if sums[c] is not None:
                outer[c] += _array(sums[c].T @ sums[c])
            if T is not None:
                pose_meat[c] += T[c] @ pose[1] @ T[c].T
    meat = outer - np.einsum("ci,cj->cij", total, total) / max(groups, 1)
    return (meat if clusters is None else cr1_factor(groups, n, D) * meat) + pose_meat


def _on_device(block, rows: tuple[int, int], mu, J, codes, C: int) -> list:
    """Per channel the products of a block's ``rows`` (:func:`_products`) formed on the run's
    device (:func:`_device_products`, in this thread: the tasks only combine them), or None (to
    be formed on the host) where ``J`` is sparse: many parameters, whose sparse scores the host
    keeps sparse."""
    if not dense_jacobian(J[0]):
        return [None] * C
    return _device_products([_operands(block, rows, mu, J, codes, c) for c in range(C)])


def _own_monomials(view, mu: np.ndarray, J: list, codes: np.ndarray) -> tuple:
    """``(coefficients, μ, J, codes)`` to score ``view`` with: for a view mapped to fewer
    monomials that can ``lift`` (a known weight substituted,
    :class:`~methods.symbolic.survey.known.Substitution`), its own coefficients with ``μ`` and
    ``J`` lifted to its own monomials (``(A M) J = A (M J)``: no block is mapped); else as given."""
    if not hasattr(view, "lift"):
        return view, mu, J, codes
    return view.coeffs, np.stack(view.lift(mu, codes)), [sp.csr_matrix(j) for j in view.lift(J, codes)], view.old_codes


def _chunks(view, y_view, weights):
    """``(block, y rows, weight rows, first row, (lo, hi))`` of each chunk of rows of each block of
    a view (:func:`_row_chunks`), the blocks loaded one by one."""
    start = 0
    for block, y_block, w_block in row_blocks(view, y_view, weights):
        for rows in _row_chunks(block):
            yield block, y_block, w_block, start, rows
        start += block.n_rows


def _row_chunks(block) -> list[tuple[int, int]]:
    """``[lo, hi)`` row ranges of a block holding at most about :data:`SCORE_CHUNK_NNZ` stored
    coefficients of one channel each (cut by channel 0's rows; a single row may exceed it)."""
    count = stored_per_row(block.a[0]) if block.b is None else stored_per_row(block.a[0]) + stored_per_row(block.b[0])
    cuts = np.searchsorted(count, np.arange(SCORE_CHUNK_NNZ, count[-1], SCORE_CHUNK_NNZ), side="right") - 1
    edges = np.unique(np.concatenate([[0], cuts[cuts > 0], [block.n_rows]]))
    return list(zip(edges[:-1].tolist(), edges[1:].tolist()))


def _chunk_terms(block, rows: tuple[int, int], y, w_pix, mu, J, codes, own, c: int, member, G, products=None):
    """One task of :func:`score_meat`: the scores of a block's ``rows`` in channel ``c``
    (:func:`_score`; ``products`` as :func:`_products` gives them, or None to form them here, on the host)
    reduced by :func:`_block_terms` (``G``: the rows' pose sensitivity or None)."""
    if products is None:
        products = _products(*_operands(block, rows, mu, J, codes, c))
    s, ds = _score(products, y[:, c], w_pix, own, slope=G is not None)
    return _block_terms(s, ds, member, None if G is None else G[:, c])


def _block_terms(s: sp.csr_matrix, ds: sp.csr_matrix | None, member: sp.csr_matrix | None, G: np.ndarray | None
                 ) -> tuple[np.ndarray, object, np.ndarray | None]:
    """A block's scores ``s`` summed over its pixels, and their outer product ``sᵀs`` (dense) or,
    with the ``(clusters, n)`` 0/1 ``member``, their sums per cluster (sparse); with the pose
    sensitivity ``G`` ``(n, k)`` of its residuals, ``dsᵀG`` ``(D, k)`` (``ds``: ∂s_p/∂r_p)."""
    slope = None if G is None else np.asarray(ds.T @ G)
    return np.asarray(s.sum(axis=0)).ravel(), _array(s.T @ s) if member is None else member @ s, slope


def _operands(block, rows: tuple[int, int], mu, J, codes, c: int) -> tuple:
    """``(A, B, μ, J)`` of channel ``c`` of a block's ``rows`` ``[lo, hi)``: the rows of its
    coefficient matrices (``B`` None without halves; the task copies only its own channel's rows),
    and ``μ`` and ``J`` on the block's monomials, ``J`` dense for few parameters
    (:func:`~methods.symbolic.system.pixel_matrices.dense_jacobian`), else CSR."""
    lo, hi = rows
    cut = (lambda m: m) if (lo, hi) == (0, block.n_rows) else (lambda m: m[lo:hi])   # noqa: E731
    at = np.searchsorted(codes, block.codes)                 # the block's columns in ``codes``
    mu_v, J_v = mu[c, at], J[c][at]
    # sparse scores: a pixel's paths touch a few of the D parameters, so sᵀs costs
    # Σ_p nnz(s_p)² instead of pixels × D² (dense); dense ones for few parameters, the
    # coefficients times a dense J (one pass over their entries, no sparse product)
    J_v = J_v.toarray() if dense_jacobian(J_v) else J_v
    return cut(block.a[c]), None if block.b is None else cut(block.b[c]), mu_v, J_v


def _products(A, B, mu, J) -> list[tuple]:
    """``[(A μ, A J), (B μ, B J)]`` (``B`` None: the first only) on the host, ``M J`` dense where
    ``J`` is, else CSR."""
    form = np.asarray if isinstance(J, np.ndarray) else (lambda m: m.tocsr())       # noqa: E731
    return [(M @ mu, form(M @ J)) for M in (A, B) if M is not None]


def _device_products(operands: list[tuple]) -> list[list[tuple]]:
    """:func:`_products` of each of ``operands`` (``(A, B, μ, J)`` with a dense ``J``, as
    :func:`_operands` gives them) on the run's device, all in one evaluation
    (:func:`~methods.symbolic.system.device_products.device_products`: ``M [J | μ]``)."""
    pairs = [(M, np.column_stack([J, mu])) for A, B, mu, J in operands for M in (A, B) if M is not None]
    out = iter(device_products(pairs))
    return [[(p[:, -1], p[:, :-1]) for p in (next(out) for M in (A, B) if M is not None)]
            for A, B, _, _ in operands]


def _score(products: list[tuple], y: np.ndarray, w_pix, own, *, slope: bool = False
           ) -> tuple[sp.csr_matrix, sp.csr_matrix | None]:
    """The ``(n, D)`` scores ``s_p`` in one channel of a block's rows from the products
    ``[(A μ, A J), (B μ, B J)]`` (:func:`_products`; dense for a dense ``J``, else CSR) and the
    rows' observed pixels ``y``, and (``slope``) their derivatives ``∂s_p/∂r_p`` by the pixel's
    residual, else None (:func:`score_meat`)."""
    (A_mu, aJ), *halves = products
    ra = A_mu - y
    if not halves:
        s = rows_times(aJ, 2.0 * ra)
        ds = 2.0 * aJ if slope else None
    else:
        (B_mu, bJ), = halves
        rb = B_mu - y
        s = rows_times(aJ, rb) + rows_times(bJ, ra)
        ds = aJ + bJ if slope else None
    if w_pix is not None:            # the weighted cost's term: w_p times the unweighted one
        s, ds = rows_times(s, w_pix), None if ds is None else rows_times(ds, w_pix)
    if own is not None:              # estimating equations: a pixel scores its owners only
        own = own if sp.issparse(s) else own.toarray()
        s, ds = _elementwise(s, own), None if ds is None else _elementwise(ds, own)
    return s, ds


def _elementwise(m, own):
    """``m ∘ own`` (both dense, or both sparse: CSR)."""
    return sp.csr_matrix(m.multiply(own)) if sp.issparse(m) else m * own


def _array(m) -> np.ndarray:
    """A dense or sparse matrix as an array."""
    return m.toarray() if sp.issparse(m) else np.asarray(m)
