"""How well the model explains each material's pixels: a fit judged without ground truth.

A std says how far the estimate moves with the noise; it cannot say whether the model explains
the photographs. An object the model lacks (a car parked on the pavement in every view) is
invisible to it when the robust weights take it for the material: the fit then follows the
object and the std, computed from the same residuals, is small (an estimate 0.07 for a true 0.20
at std 0.016 on such a courtyard). So each material's pixels are compared with the noise the fit
expects there, per view and over all views:

- the residual ``r_p = μ_p(ρ̂) - y_p`` of every usable pixel (scene weight > 0) against its
  expected spread ``σ_p² = s_v² + v_p``: ``v_p`` the Monte Carlo variance of the pixel's own
  prediction (its two half-sample estimates, :func:`~methods.symbolic.misfit.robust_scale.pixel_variance`),
  ``s_v`` the view's robust scale of the residuals (:func:`~methods.symbolic.misfit.robust_scale.robust_scale`,
  per channel: what the fit takes for the observation's noise);
- ``chi2``: the mean of ``(r_p / σ_p)²`` over the material's pixels the fit kept (robust weight
  at least :data:`~methods.symbolic.misfit.robust_scale.LEFT_OUT`) and channels, about 1 where the model
  explains them (its square root is the Birge ratio);
- ``dropped``: the share of the material's usable pixels the robust weights left out.

A material whose robust weights left out more than :data:`DROP_MAX` of its pixels over all
views, or whose kept pixels' ``chi2`` exceeds :data:`CHI2_MAX`, is a poor fit: its weights are
flagged ill-determined with the reason (results.json ``fit_quality``, the parameters'
``ill_determined`` and ``why``). Flagged, not inflated: the sandwich std already grows with the
size of the residuals it is computed from (a Birge-ratio inflation would count them twice), and
what it misses, the bias of a fit that follows an unmodelled object, no factor on the std bounds.
"""
from __future__ import annotations

import numpy as np

from methods.symbolic.misfit.robust_scale import LEFT_OUT, pixel_variance, robust_scale
from methods.symbolic.system.coefficients import predicted_with_variance

#: share of a material's usable pixels the robust weights may leave out (over all views) before
#: its fit counts as poor
DROP_MAX = 0.25
#: mean squared standardised residual of a material's kept pixels above which its fit is poor
#: (a Birge ratio of 2)
CHI2_MAX = 4.0


def material_fit(problem, views, mu: np.ndarray, codes: np.ndarray, segments: dict) -> dict:
    """results.json ``fit_quality``: per material (segment name) its ``chi2``, ``dropped``,
    ``pixels``, ``poor``, ``why`` and the same per view (``views``).

    Parameters
    ----------
    problem : Problem
        Its scene names the segments.
    views : list
        The field fit's views (``name``, ``shape``, ``coeffs``, ``y``, ``scene_w``, ``robust_w``).
    mu : numpy.ndarray
        ``(C, N)`` monomials at the estimate, over ``codes``.
    segments : dict
        View name -> ``(H, W)`` segment index seen by each pixel (-1: sky).
    """
    sums: dict[int, dict] = {}
    per_view: dict[int, dict] = {}
    for v in views:
        seg = np.asarray(segments[v.name]).ravel()
        z2, kept, usable = _standardised(v, mu, codes)
        for g in np.unique(seg[usable & (seg >= 0)]):
            mine = usable & (seg == g)
            counts = _counts(z2, kept, mine)
            per_view.setdefault(int(g), {})[v.name] = _summary(counts)
            total = sums.setdefault(int(g), {"n": 0, "kept": 0, "z2": 0.0, "z2_n": 0})
            for key, value in counts.items():
                total[key] += value
    names = {i: s.name for i, s in enumerate(problem.scene.segments)}
    return {names[g]: {**_summary(total), **_verdict(_summary(total), per_view[g]), "views": per_view[g]}
            for g, total in sorted(sums.items())}


def _standardised(v, mu: np.ndarray, codes: np.ndarray):
    """``(z², kept, usable)`` of a view's pixels: squared standardised residuals (n, C), the pixels
    the robust weights kept and those the scene lets the fit use."""
    pred, raw = predicted_with_variance(v.coeffs, mu, codes)
    var = pixel_variance(raw, v.shape)
    usable = np.ones(len(v.y), bool) if v.scene_w is None else np.asarray(v.scene_w) > 0
    r = pred - v.y
    s = robust_scale(r[usable], var[usable]) if usable.any() else np.zeros(r.shape[1])
    spread = s[None, :] ** 2 + var
    with np.errstate(divide="ignore", invalid="ignore"):
        z2 = np.where(spread > 0, r ** 2 / spread, 0.0)
    kept = usable if v.robust_w is None else usable & (np.asarray(v.robust_w) >= LEFT_OUT)
    return z2, kept, usable


def _counts(z2: np.ndarray, kept: np.ndarray, mine: np.ndarray) -> dict:
    inside = kept & mine
    return {"n": int(mine.sum()), "kept": int(inside.sum()), "z2": float(z2[inside].sum()),
            "z2_n": int(inside.sum() * z2.shape[1])}


def _summary(c: dict) -> dict:
    return {"pixels": c["n"], "dropped": 1.0 - c["kept"] / c["n"] if c["n"] else 0.0,
            "chi2": c["z2"] / c["z2_n"] if c["z2_n"] else None}


def _verdict(total: dict, views: dict) -> dict:
    """``poor`` and ``why`` of a material from its summary over all views and per view."""
    if total["dropped"] > DROP_MAX:
        worst = max(views, key=lambda n: views[n]["dropped"])
        return {"poor": True, "why": (f"the robust weights left out {100 * total['dropped']:.0f} % of its pixels "
                                      f"(up to {100 * views[worst]['dropped']:.0f} % in {worst}): something the "
                                      "model lacks covers it, and the fit may follow it; mask it or model it")}
    if total["chi2"] is not None and total["chi2"] > CHI2_MAX:
        return {"poor": True, "why": (f"its kept pixels' residuals are {np.sqrt(total['chi2']):.1f} times the noise "
                                      "the fit expects (Birge ratio): the model does not explain this material")}
    return {"poor": False, "why": None}


def poor_parameters(quality: dict | None, parameters) -> tuple[np.ndarray, list]:
    """``(P,)`` bool of the parameters whose material is a poor fit, and each one's reason (None
    where not poor)."""
    quality = quality or {}
    flags = [bool((quality.get(p.segment_name) or {}).get("poor")) for p in parameters]
    why = [(quality[p.segment_name]["why"] if f else None) for p, f in zip(parameters, flags)]
    return np.array(flags, bool), why
