"""Clusters of neighbouring pixels for the cluster-robust sandwich (``method.std=cluster``).

The pixel sandwich (:func:`~methods.symbolic.uncertainty.sandwich_meat.score_meat`) treats every pixel's score
as independent. Photographs break that: bilinear resampling of a distorted camera, JPEG's 8x8
blocks, a misregistered edge or texture the model lacks make neighbouring residuals one error,
and the pixel sandwich then understates the variance by about the number of pixels one error
spans. The cluster-robust sandwich (Liang and Zeger 1986; Cameron and Miller 2015, "A
practitioner's guide to cluster-robust inference") sums the scores within clusters before the
outer product, so that errors correlated within a cluster count once:

    M = c · Σ_g (S_g - S̄)(S_g - S̄)ᵀ,   S_g = Σ_{p ∈ g} s_p,   c = G/(G - 1) · (N - 1)/(N - K)

(``G`` clusters, ``N`` pixels, ``K`` parameters: the CR1 small-sample correction).

Clusters here are squares of ``side`` x ``side`` pixels of one segment in one view
(:func:`cluster_ids`). ``side`` is measured from the residuals at the estimate
(:func:`correlation_length`): the smallest lag at which their autocorrelation, pooled over the
views, channels, both image axes and the pixel pairs within one segment, falls below
:data:`CORRELATION_FLOOR`; twice that lag, so that most correlated pairs share a cluster, clipped
to [1, :data:`MAX_SIDE`]. With independent residuals the side is 2 and the cluster sandwich
agrees with the pixel one within its own noise.
"""
from __future__ import annotations

import numpy as np

#: autocorrelation below which two residuals count as independent
CORRELATION_FLOOR = 0.1
#: largest cluster side in pixels (and largest lag measured)
MAX_SIDE = 32


def _lag_correlation(r: np.ndarray, same: np.ndarray, lag: int, axis: int) -> tuple[float, float, int]:
    """Sums (Σ r_i r_j, Σ (r_i² + r_j²)/2, pairs) over the pixel pairs ``lag`` apart along ``axis``
    that lie in one segment (``same`` masks usable pixels by segment id, -1: not used)."""
    n = r.shape[axis]
    if lag >= n:
        return 0.0, 0.0, 0
    a = np.take(r, range(0, n - lag), axis=axis)
    b = np.take(r, range(lag, n), axis=axis)
    sa = np.take(same, range(0, n - lag), axis=axis)
    sb = np.take(same, range(lag, n), axis=axis)
    pair = (sa == sb) & (sa >= 0)
    if not pair.any():
        return 0.0, 0.0, 0
    a, b = a[pair], b[pair]
    return float(np.sum(a * b)), float(np.sum(a * a + b * b) / 2.0), int(pair.sum())


def correlation_length(residuals: list[np.ndarray], segments: list[np.ndarray],
                       weights: list[np.ndarray | None]) -> tuple[int, list[float]]:
    """The lag (pixels) at which the residuals' within-segment autocorrelation falls below
    :data:`CORRELATION_FLOOR`, and the autocorrelation at lags 1, 2, ... (module docstring).

    Parameters
    ----------
    residuals : list of numpy.ndarray
        Per view, ``(H, W, C)`` residuals at the estimate.
    segments : list of numpy.ndarray
        Per view, ``(H, W)`` segment ids (-1: sky).
    weights : list
        Per view, ``(H, W)`` pixel weights of the fit (0: left out), or None.
    """
    rho = []
    for lag in range(1, MAX_SIDE + 1):
        num = den = 0.0
        for r, seg, w in zip(residuals, segments, weights):
            same = np.where(seg >= 0 if w is None else (seg >= 0) & (w > 0), seg, -1)
            centred = np.zeros_like(r, dtype=np.float64)
            for s in np.unique(same[same >= 0]):             # each segment's mean removed
                mask = same == s
                centred[mask] = r[mask] - r[mask].mean(axis=0)
            for c in range(r.shape[2]):
                for axis in (0, 1):
                    n_, d_, _ = _lag_correlation(centred[..., c], same, lag, axis)
                    num, den = num + n_, den + d_
        rho.append(num / den if den > 0 else 0.0)
        if rho[-1] < CORRELATION_FLOOR:
            return lag, rho
    return MAX_SIDE, rho


def side_for(length: int) -> int:
    """Cluster side for a correlation length (module docstring)."""
    return int(np.clip(2 * length, 1, MAX_SIDE))


def cluster_ids(segments: np.ndarray, side: int) -> np.ndarray:
    """``(H·W,)`` cluster id of each pixel: its ``side`` x ``side`` square and its segment
    (consecutive ids from 0; the sky, -1, clusters like a segment: its scores are 0)."""
    H, W = segments.shape
    y, x = np.mgrid[0:H, 0:W]
    key = (segments.astype(np.int64) + 1) * ((H // side + 1) * (W // side + 1)) + (y // side) * (W // side + 1) + x // side
    _, ids = np.unique(key.ravel(), return_inverse=True)
    return ids.astype(np.int64)


def cr1_factor(n_clusters: int, n_pixels: int, n_params: int) -> float:
    """CR1 small-sample correction ``G/(G - 1) · (N - 1)/(N - K)`` (Cameron and Miller 2015)."""
    if n_clusters < 2 or n_pixels <= n_params:
        return 1.0
    return n_clusters / (n_clusters - 1) * (n_pixels - 1) / (n_pixels - n_params)


def view_clusters(problem, views, basis, rho: np.ndarray) -> tuple[list[np.ndarray], dict]:
    """The clusters of every view of a fit and what they were sized from.

    Parameters
    ----------
    problem : Problem
        Its cameras, in the order of ``views``.
    views : iterable
        ``(coefficients, y, weights or None)`` per view, as the fit's sandwich reads them.
    basis : MonomialBasis
        The fit's basis over all its parameters; ``rho`` ``(D, C)`` the estimate over them (0
        where a parameter is not estimated: its monomials vanish).

    Returns
    -------
    (list of numpy.ndarray, dict)
        Per view the ``(n,)`` cluster ids; ``{"side", "correlation_length", "autocorrelation"}``
        (results.json ``std_clusters``).
    """
    from framework.render.mitsuba_scene import segment_maps
    from methods.symbolic.system.coefficients import predicted
    maps = segment_maps(problem.scene, problem.cameras)
    C = rho.shape[1]
    mu = np.stack([basis.evaluate(rho[:, c]) for c in range(C)])
    residuals, segments, weights = [], [], []
    for cam, (coeffs, y, *w) in zip(problem.cameras, views):
        shape = (cam.height, cam.width)
        r = predicted(coeffs, mu, basis.codes) - np.asarray(y, float).reshape(-1, C)
        residuals.append(r.reshape(*shape, C))
        segments.append(maps[cam.name])
        weights.append(None if not w or w[0] is None else np.asarray(w[0], float).reshape(shape))
    length, profile = correlation_length(residuals, segments, weights)
    side = side_for(length)
    ids = [cluster_ids(seg, side) for seg in segments]
    return ids, {"side": side, "correlation_length": length, "autocorrelation": [round(x, 4) for x in profile]}
