"""Robust weights of a view's pixels against objects the model lacks (``method.robust``).

After each solve of the field path's iteratively reweighted least squares, the residuals
``r_{p,c}`` of every pixel are divided by a robust scale per view and channel, ``s = max(1.4826·MAD(r),
σ_q)`` (``σ_q``: the median quantisation noise of the delivered 8/16-bit encoding, so that
quantisation never makes an outlier), widened per pixel by the Monte Carlo variance ``v_{p,c}``
of the pixel's own prediction (from its two half-sample estimates,
:func:`~methods.symbolic.system.coefficients.predicted_with_variance`), combined over channels into
``t_p = sqrt(mean_c r_{p,c}² / (s_c² + v_{p,c}))``, and the pixel gets the weight ``ψ(t)/t`` of the Cauchy
(``1/(1 + (t/2.385)²)``) or Huber (``min(1, 1.345/t)``) loss (95 % Gaussian efficiency
each). A car or a pedestrian the model lacks leaves residuals many times the scale and is
weighted out. Why the pixel's own variance: an unbiased Monte Carlo pass
is heavy-tailed (a few pixels drew a rare bright path); measured against the view's scale
alone those pixels look like outliers and were weighted out, which biased ρ by up to 15 std
on clean linear images (tests/methods/test_consistency.py); against their own variance
they are not. The rounds themselves are the field path's (:mod:`methods.symbolic.fit.field`).
"""
from __future__ import annotations

import numpy as np

from methods.symbolic.misfit.robust_scale import cauchy_weight, robust_scale
from methods.symbolic.options import ROBUST_LOSSES

#: Huber tuning constant at 95 % efficiency for Gaussian residuals (Cauchy's: robust_scale.CAUCHY_K)
HUBER_K = 1.345


def robust_weights(residual: np.ndarray, used: np.ndarray, *, loss: str, floor: np.ndarray | float = 0.0,
                   variance: np.ndarray | None = None) -> np.ndarray:
    """``(n,)`` IRLS weights of one view's pixels (module docstring).

    Parameters
    ----------
    residual : numpy.ndarray
        ``(n, C)`` residuals ``prediction - observation``.
    used : numpy.ndarray
        ``(n,)`` bool: pixels with a non-zero scene weight (the scale is taken over them).
    loss : str
        ``cauchy`` or ``huber`` (``none``: all ones).
    floor : float or numpy.ndarray
        Smallest scale per channel (the quantisation noise).
    variance : numpy.ndarray, optional
        ``(n, C)`` Monte Carlo variance of each pixel's prediction
        (:func:`~methods.symbolic.system.coefficients.predicted_with_variance`): a pixel's residual is
        measured against ``sqrt(scale² + variance)``, so a pixel whose pass drew a rare bright
        path is not taken for an outlier. Down-weighting those would drop the very samples that
        keep the estimate unbiased (measured on the tiny scene's clean linear images: the
        per-pixel weights alone moved ρ by up to 15 std).
    """
    n, C = residual.shape
    if loss == "none" or not used.any():
        return np.ones(n)
    r = residual[used]
    spread = robust_scale(r - np.median(r, axis=0), None if variance is None else variance[used])
    scale = np.maximum(spread, np.broadcast_to(np.asarray(floor, float), (C,)))
    scale = np.maximum(scale, 1e-12 * (np.abs(r).max() + 1e-30))
    spread = scale ** 2 if variance is None else scale ** 2 + variance
    t = np.sqrt(np.mean(residual ** 2 / spread, axis=1))
    if loss == "cauchy":
        return cauchy_weight(t)
    if loss == "huber":
        return np.minimum(1.0, HUBER_K / np.maximum(t, 1e-300))
    raise ValueError(f"robust loss '{loss}' unknown; use one of {', '.join(ROBUST_LOSSES)}")
