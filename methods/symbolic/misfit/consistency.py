"""Objects the model lacks, found by the views' disagreement (``method.consistency``).

The estimator
    A surface point of the model has one reflectance, so once the model predicts it, every view
    that sees it unoccluded (in the model) leaves the same *relative residual*
    ``e = (y - ŷ) / ŷ`` there, up to noise: the prediction ``ŷ`` carries what differs between
    views (the light's direction-dependent part, specular reflection, each view's gain), and a
    reflectance that is still wrong shifts ``e`` alike in every view. A parked van in front of
    the pavement in view ``v`` does not: ``e_v`` differs from the other views' at the same points.
    For each pixel ``p`` of ``v`` whose model point ``X`` is seen by at least :data:`MIN_OTHERS`
    other views (:func:`framework.render.correspondence.visible_pairs`: projection, a shadow ray
    to each camera, the same segment at the pixel found there), the disagreement is
    ``d = e_v(p) - median(e_v(p), e_u(q_u) for every such u)`` per channel (the median of three or
    more values, the view's own included: one view that disagrees cannot move it); standardised by
    ``sqrt(s² + v_p)``, ``v_p`` the Monte Carlo variance of the pixel's own prediction (relative)
    and ``s`` the robust scale of every compared pixel of every view
    (:func:`~methods.symbolic.misfit.robust_scale.robust_scale`, per channel), to
    ``t`` (the RMS over channels), it weighs the pixel ``1 / (1 + (t / 2.385)²)`` (Cauchy, 95 % efficiency for
    Gaussian ``d``). Pixels with fewer other views keep the per-pixel robust weights
    (``method.robust``) as before.

Breakdown
    A pixel's test depends on the other views only through a median of at least three values: it
    holds while fewer than half of the views that see a point have an object in front of it there,
    whatever share of a segment's pixels the object covers in one view (where a per-pixel
    M-estimator on one view's residuals breaks down once the object is a large share of a
    segment's pixels, and fits it). The scale is a median over every view's compared pixels: it
    holds while under half of all of those disagree (an object covering most of one view of
    several is a minority of the pool). Points seen by one other view only cannot tell
    which view is wrong and are left to the per-pixel weights.

What it cannot find
    What every view shows alike. Measured on urban_canyon_field (200², all views): the window's
    ρ_d / ρ_s bias (+0.02 / −0.035), much of it from a blur every photograph has and the model's
    pixels lack (the resampling of distorted photographs, JPEG), and the asphalt's (−0.005), from the
    masked car's shadow and the sky it hides, are unchanged with ``method.consistency=auto``; a
    wall's (0.003 → 0.0015) is what it removes there.

The test runs before the first solve, at the start (the high-breakdown start: a wrong
reflectance moves every view's ``e`` alike, so the start need not be right), and after every
robust round at the new estimate.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from methods.symbolic.misfit.robust_scale import cauchy_weight, robust_scale

#: the other views that must see a point for its test (a median of two or more)
MIN_OTHERS = 2
#: ``ŷ`` is floored at this fraction of the view's median prediction (per channel): dark pixels
#: would otherwise blow the relative residual up
DARK_FRACTION = 0.05


@dataclass(frozen=True)
class ViewPairs:
    """The correspondences of a run's views: ``pairs[(v, u)] = (p, q)``, view indices in
    ``names`` order, pixels row-major (:func:`~framework.render.correspondence.visible_pairs`)."""

    names: tuple[str, ...]
    sizes: tuple[int, ...]
    pairs: dict

    @classmethod
    def of(cls, problem) -> "ViewPairs":
        from framework.render.correspondence import visible_pairs
        surf, pairs = visible_pairs(problem.scene, list(problem.cameras))
        kept = {}
        for (v, u), (p, q) in pairs.items():
            same = surf[v].segment[p] == surf[u].segment[q]      # not across an edge
            kept[(v, u)] = (p[same], q[same])
        return cls(tuple(c.name for c in problem.cameras), tuple(c.width * c.height for c in problem.cameras), kept)

    def weights(self, observed: dict, predicted: dict, usable: dict, variance: dict | None = None) -> dict:
        """View name -> ``(n,)`` consistency weights, NaN where the pixel has fewer than
        :data:`MIN_OTHERS` other views to compare with (module docstring).

        ``observed``, ``predicted``: name -> ``(n, C)``; ``usable``: name -> ``(n,)`` bool (pixels
        with a non-zero scene weight: masked pixels neither are tested nor testify); ``variance``:
        name -> ``(n, C)`` Monte Carlo variance of each prediction, which widens the pixel's own
        scale (a pass's rare bright path is not an object the model lacks).
        """
        e = {n: _relative(observed[n], predicted[n]) for n in self.names}
        V = len(self.names)
        tested, d, own = {}, {}, {}
        for v, name in enumerate(self.names):
            C = e[name].shape[1]
            others = np.full((self.sizes[v], V, C), np.nan)
            for u, other in enumerate(self.names):
                if (v, u) in self.pairs:
                    p, q = self.pairs[(v, u)]
                    ok = usable[other][q]
                    others[p[ok], u] = e[other][q[ok]]
            count = np.isfinite(others[:, :, 0]).sum(axis=1)
            tested[name] = t = np.flatnonzero((count >= MIN_OTHERS) & usable[name])
            others[t, v] = e[name][t]              # the median of all views that see the point
            d[name] = e[name][t] - np.nanmedian(others[t], axis=1)
            own[name] = 0.0 * d[name] if variance is None else variance[name][t] / _floored(predicted[name])[t] ** 2
        pooled = np.concatenate([d[n] for n in self.names])
        own_all = None if variance is None else np.concatenate([own[n] for n in self.names])
        scale = robust_scale(pooled, own_all) if len(pooled) else None
        out = {}
        for v, name in enumerate(self.names):
            w = np.full(self.sizes[v], np.nan)
            if scale is not None:
                w[tested[name]] = _cauchy(d[name], np.sqrt(scale ** 2 + own[name]))
            out[name] = w
        return out


def _floored(y_hat: np.ndarray) -> np.ndarray:
    """``max(ŷ, floor)`` per channel (floor: :data:`DARK_FRACTION` of the median ŷ)."""
    return np.maximum(y_hat, DARK_FRACTION * np.maximum(np.median(y_hat, axis=0), 1e-12))


def _relative(y: np.ndarray, y_hat: np.ndarray) -> np.ndarray:
    """``(y - ŷ) / max(ŷ, floor)`` per channel (:func:`_floored`)."""
    return (y - y_hat) / _floored(y_hat)


def _cauchy(d: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Cauchy weights of disagreements ``d`` (m, C) standardised by ``scale`` ((C,) or per pixel
    (m, C)), ``t`` the RMS over the channels."""
    t = np.sqrt(np.mean((d / scale) ** 2, axis=1))
    return cauchy_weight(t)
