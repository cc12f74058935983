"""Per-view exposure gains in the symbolic fit (scene.yaml ``photometry: exposure: per_view``).

A photograph is ``g_{v,c} · L_v(ρ)``: one unknown gain per view and channel multiplies every
monomial of the view, so the pixel stays a polynomial, of degree ``N_max + 1``, in the
parameters ``(ρ, h)``. Each non-reference view ``v`` gets a parameter ``h_v = g_v / G_MAX``
in ``[0, 1]`` (the solver's box; :data:`GAIN_MAX`), and every monomial of its pixels is
multiplied by ``h_v`` (:func:`with_gain`): the gains are solved jointly with ρ, exactly,
and their standard errors come from the same sandwich as ρ's. The reference view's gains
are 1 and fix the scale, which the data cannot (``g·L(ρ)`` = ``(g/s)·L(sρ)`` at first order).
The field path (:mod:`methods.symbolic.fit.field`) adds the parameters, starting each gain at
its closed-form guess (:func:`gain_guess`).
"""
from __future__ import annotations

import numpy as np

from methods.symbolic.system.coefficients import TiledCoefficients, ViewCoefficients, predicted
from methods.symbolic.system.pixel_matrices import moved_columns
from methods.symbolic.trace.monomial_codes import code_digits, encode_digits

#: ``segment_name`` of a view's gain parameter: this prefix, then the view's name
GAIN_PREFIX = "exposure:"
#: largest gain representable: h = g / GAIN_MAX lies in the solver's box [0, 1]
GAIN_MAX = 4.0


def with_gain(coeffs, *, n_params: int, max_degree: int, n_total: int, gain: int | None):
    """A view's coefficients in the basis of ``n_total`` parameters and degree ``max_degree + 1``.

    Parameters
    ----------
    coeffs : ViewCoefficients or TiledCoefficients
        Over ``n_params`` parameters of degree at most ``max_degree`` (multiset codes, base
        ``n_params + 1``, :mod:`methods.symbolic.system.basis`). Tiled ones are relabelled block by
        block and held in memory (the field fit reweights them every round).
    n_params, max_degree : int
        The pass's ``D`` and ``N_max``.
    n_total : int
        ``D`` plus the gain parameters.
    gain : int or None
        Index (``>= n_params``) of this view's gain parameter: every monomial is multiplied by it
        and the coefficients by :data:`GAIN_MAX`; None for the reference view (only relabelled).

    Returns
    -------
    ViewCoefficients or TiledCoefficients
        As ``coeffs``, columns sorted by their new codes.
    """
    if isinstance(coeffs, TiledCoefficients):
        blocks = [with_gain(b, n_params=n_params, max_degree=max_degree, n_total=n_total, gain=gain)
                  for _, b in coeffs.blocks()]
        return TiledCoefficients(coeffs.starts, blocks, coeffs.n_rows)
    digits = code_digits(np.asarray(coeffs.codes, np.int64), n_params, max_degree)
    degree = (digits > 0).sum(axis=1)
    wide = np.zeros((len(digits), max_degree + 1), dtype=np.int64)
    wide[:, :max_degree] = digits
    scale = 1.0
    if gain is not None:
        # the gain's index exceeds every ρ index: appended after the used digits, it keeps them sorted
        wide[np.arange(len(wide)), degree] = gain + 1
        scale = GAIN_MAX
    codes = encode_digits(wide, n_total)
    order = np.argsort(codes, kind="stable")
    position = np.empty(len(order), np.int64)
    position[order] = np.arange(len(order))           # old column j goes to position[j]
    relabel = lambda mats: None if mats is None else [moved_columns(m, position, scale) for m in mats]  # noqa: E731
    return ViewCoefficients(relabel(coeffs.a), relabel(coeffs.b), float(coeffs.split), codes[order])


def gain_guess(coeffs, y: np.ndarray, weights: np.ndarray | None, mu: np.ndarray, codes: np.ndarray
               ) -> np.ndarray:
    """``(C,)`` least-squares gains ``Σ w m y / Σ w m²`` of a view whose unit-gain image at the
    guess is ``m`` (the closed form of the gain for a fixed ρ), in ``[0, GAIN_MAX]``."""
    m = predicted(coeffs, mu, codes)
    y = np.asarray(y, dtype=np.float64).reshape(m.shape)
    w = np.ones(len(m)) if weights is None else np.asarray(weights, float)
    num, den = (w[:, None] * m * y).sum(axis=0), (w[:, None] * m * m).sum(axis=0)
    g = np.where(den > 0, num / np.where(den > 0, den, 1.0), 1.0)
    return np.clip(g, 0.0, GAIN_MAX)
