"""Metrics of a held-out view: a prediction against its photograph (``holdout`` in results.json).

Over the pixels the run would have used (the scene's pixel weights: masks, saturation), whole
image and per segment: RMSE per channel and PSNR on linear radiance, PSNR and SSIM on the sRGB
image (linear values clipped to [0, 1] first, as a display would), and ``z_rms``, the RMS of
the residuals in units of their predicted std (1 when that std is honest).
"""
from __future__ import annotations

import numpy as np

from framework.images import srgb_encode


def _finite(x: float) -> float | None:
    """``x``, or None where JSON has no number for it (an infinite PSNR of identical images)."""
    return float(x) if np.isfinite(x) else None


def _psnr(mse: float, peak: float) -> float | None:
    return None if mse <= 0 or peak <= 0 else _finite(10.0 * np.log10(peak * peak / mse))


def ssim_map(observed: np.ndarray, predicted: np.ndarray) -> np.ndarray | None:
    """``(H, W)`` SSIM of the sRGB images (scikit-image, data range 1, window 7 or the largest
    odd one that fits), None below 3x3 pixels."""
    from skimage.metrics import structural_similarity
    side = min(observed.shape[:2])
    win = min(7, side if side % 2 else side - 1)
    if win < 3:
        return None
    _, full = structural_similarity(observed, predicted, data_range=1.0, channel_axis=-1, win_size=win, full=True)
    return full.mean(axis=-1)


def region_metrics(observed: np.ndarray, predicted: np.ndarray, used: np.ndarray, *, variance: np.ndarray | None,
                   ssim: np.ndarray | None) -> dict:
    """The metrics of the pixels ``used`` ((H, W) bool) of ``observed`` and ``predicted`` ((H, W, C)
    linear).

    Parameters
    ----------
    observed, predicted : numpy.ndarray
        ``(H, W, C)`` linear radiance.
    used : numpy.ndarray
        ``(H, W)`` bool, the pixels that count.
    variance : numpy.ndarray or None
        Predicted variance of each residual, ``(H, W, C)`` or broadcast to it (``(C,)``: one per
        channel); None: ``z_rms`` is None.
    ssim : numpy.ndarray or None
        ``(H, W)`` SSIM map of the whole sRGB image (:func:`ssim_map`), averaged over ``used``.

    Returns
    -------
    dict
        ``pixels``, ``rmse`` (per channel), ``psnr``, ``psnr_srgb``, ``ssim``, ``z_rms``.
    """
    y, p = observed[used].astype(float), predicted[used].astype(float)
    r = p - y
    peak = float(y.max()) if y.size else 0.0
    y8, p8 = srgb_encode(np.clip(y, 0, 1)), srgb_encode(np.clip(p, 0, 1))
    z = None
    if variance is not None:
        var = np.broadcast_to(variance, observed.shape)[used]
        ok = var > 0
        z = _finite(np.sqrt(np.mean(r[ok] ** 2 / var[ok]))) if ok.any() else None
    return {"pixels": int(used.sum()), "rmse": [float(x) for x in np.sqrt(np.mean(r * r, axis=0))],
            "psnr": _psnr(float(np.mean(r * r)), peak), "psnr_srgb": _psnr(float(np.mean((p8 - y8) ** 2)), 1.0),
            "ssim": None if ssim is None else _finite(float(ssim[used].mean())), "z_rms": z}


def view_metrics(observed: np.ndarray, predicted: np.ndarray, used: np.ndarray, segment_map: np.ndarray,
                 segment_names, *, variance: np.ndarray | None = None) -> dict:
    """:func:`region_metrics` of the whole view and of each segment it sees in ``used`` pixels
    (``segments``, keyed by segment name).

    Pixels outside ``used`` get the observation in the prediction before SSIM is computed, so
    that a masked pixel inside a window does not count against the prediction.
    """
    shown = np.where(used[..., None], predicted, observed)
    ssim = ssim_map(srgb_encode(np.clip(observed, 0, 1)), srgb_encode(np.clip(shown, 0, 1)))
    out = region_metrics(observed, predicted, used, variance=variance, ssim=ssim)
    segments = {}
    for s in np.unique(segment_map[used]):
        if s >= 0:
            segments[str(segment_names[s])] = region_metrics(observed, predicted, used & (segment_map == s),
                                                             variance=variance, ssim=ssim)
    out["segments"] = segments
    return out
