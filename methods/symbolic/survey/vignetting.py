"""Lens vignetting in the symbolic fit (scene.yaml ``photometry: vignetting``).

The model
    A photograph's pixel is ``V(r) · L(ρ)`` with the lens falloff ``V(r) = 1 + a1 r² + a2 r⁴ +
    a3 r⁶`` of its COLMAP camera (views sharing a camera id share the lens) and ``r`` the
    distance of the pixel centre from the principal point divided by half the image diagonal
    (:func:`~framework.scene.lens.pixel_radius`): ``r = 1`` at the corners of an image whose principal point is its
    centre, a little more at the far corners of one whose principal point is off centre. ``r``
    is measured in the *delivered* image: for a view resampled from a distorted camera
    (:mod:`framework.scene.undistort`), at the point of the delivered image each pinhole pixel
    was interpolated from (same width, height and principal point as the pinhole camera, so the
    two agree where there is no distortion). The factor is taken at the pixel centre: over a
    pixel of a 16-pixel-wide image it varies by at most ``|dV/dr|·Δr ≈ 0.6·0.09`` at the corner
    of a 30 % falloff, and its mean over the pixel differs from the centre value only at second
    order (≈ 1e-3 there, far less on real image sizes).

Known profile (``vignetting: [a1, a2, a3]``)
    Every stored per-pixel coefficient of a view is multiplied by its pixel's ``V(r)``
    (:func:`with_factors` with one term): exact, no new unknown.

Estimated profile (``vignetting: estimate``)
    ``V`` is linear in ``(a1, a2, a3)``, so the pixel stays a polynomial. Each coefficient gets a
    parameter ``h_i`` in the solver's box ``[0, 1]``, ``a_i = A (2 h_i - 1)`` with ``A`` =
    :data:`PROFILE_BOUND` (so ``a_i ∈ [-A, A]``; ``h_i = 1/2`` is no falloff), and

        ``V(r) = c0(r) + Σ_i c_i(r) h_i``,  ``c0 = 1 - A (r² + r⁴ + r⁶)``,  ``c_i = 2 A r^{2i}``.

    Each pixel ``Γ_p μ`` becomes ``c0_p Γ_p μ + Σ_i c_ip h_i Γ_p μ``: every monomial once as it
    was (times ``c0_p``) and once per ``i`` with the digit of ``h_i`` appended (times
    ``c_ip``), so the degree grows by one. A pixel of ``k`` monomials then has ``4k``; where the
    summed system is small the field path forms the Gram matrix not from them but from seven
    products ``Γᵀ diag(w r^{2j}) Γ`` of the coefficients before the expansion (the terms' products
    are polynomials of degree 6 in ``r²``: :func:`term_products`,
    :mod:`methods.symbolic.system.row_factors`). The ``h`` parameters are numbered after ρ and the
    exposure gains, so an appended digit (after a gain digit, when ``exposure: per_view``) keeps
    the multiset codes sorted (:mod:`methods.symbolic.system.basis`). The profile is solved jointly
    with ρ, exactly, and its std comes from the same sandwich (``std(a_i) = 2 A std(h_i)``).
    The parameters are per channel like every other (the solve is per channel); the reported
    profile of a camera is the inverse-variance weighted mean over the channels, with the
    weighted mean of their std (:func:`profile_report`: an upper bound on the std of that mean
    whatever the correlation of the channels, which share the Monte Carlo paths).

Identifiability
    ``V(0) = 1`` fixes the overall scale, but a falloff and the reflectances trade off through
    the spatial pattern alone: a segment seen only near the image border, in every view, can
    take the falloff into its ρ. The profile is determined when segments (or the directly seen
    sky, whose radiance is known) are seen both near the centre and toward the corners: several
    views of one camera, each framing the scene differently, or large segments spanning the
    radius. The three coefficients are strongly correlated over ``r ∈ [0, 1]`` (their individual
    std is larger than that of ``V`` itself); the falloff at the corner, ``1 + a1 + a2 + a3``,
    is far better determined (``corner`` in the report).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from framework.scene.lens import falloff, pixel_radius
from methods.symbolic.system.pixel_matrices import FactoredColumns, expanded_columns
from methods.symbolic.system.row_factors import RowFactors
from methods.symbolic.trace.monomial_codes import appended_codes

#: ``segment_name`` of a camera's profile parameters: this prefix, then the camera's key
VIGNETTING_PREFIX = "vignetting:"
#: ``A``: each coefficient is estimated in ``[-A, A]``. 1 covers the falloffs of real lenses
#: (20-50 % at the corner is ``Σ a_i`` = -0.2..-0.5; a single ``a1 = -1`` darkens the corner
#: to 0) with room on either side, keeps ``h`` well scaled (a change of 0.01 in ``a_i`` is 0.005
#: in ``h_i``), and the data, not the box, then decide: an estimate at a bound is a sign of
#: another cause (a wrong emitter, an exposure).
PROFILE_BOUND = 1.0
#: names of the three coefficients (the parameters' ``kernel``)
COEFFICIENTS = ("a1", "a2", "a3")


def estimate_terms(r: np.ndarray, *, bound: float = PROFILE_BOUND) -> list[np.ndarray]:
    """``[c0, c1, c2, c3]``, each ``(n,)``: ``V = c0 + Σ_i c_i h_i`` with ``a_i = bound (2 h_i - 1)``."""
    powers = [np.asarray(r, float) ** (2 * i) for i in (1, 2, 3)]
    return [1.0 - bound * sum(powers)] + [2.0 * bound * p for p in powers]


def term_products(r: np.ndarray, *, bound: float = PROFILE_BOUND) -> tuple[np.ndarray, np.ndarray]:
    """The products of the :func:`estimate_terms` as combinations of the powers ``r^{2k}``,
    ``k = 0..6`` (:func:`with_factors`' ``products``):
    ``(basis (7, n), alpha (4, 4, 7))``. Each term is a polynomial of degree 3 in ``q = r²``
    (``c0 = 1 - bound (q + q² + q³)``, ``c_i = 2 bound q^i``), so each product is one of degree 6."""
    q = np.asarray(r, float).ravel() ** 2
    polys = [np.array([1.0, -bound, -bound, -bound])] + [2.0 * bound * np.eye(4)[i] for i in (1, 2, 3)]
    alpha = np.array([[np.convolve(p, u) for u in polys] for p in polys])
    return np.stack([q ** k for k in range(alpha.shape[2])]), alpha


def with_factors(coeffs, terms, *, n_params: int, max_degree: int, products: tuple | None = None):
    """``Σ_t diag(s_t) Γ`` with parameter ``j_t``'s digit appended to every monomial of term ``t``.

    Parameters
    ----------
    coeffs : ViewCoefficients or TiledCoefficients
        Over ``n_params`` parameters (multiset codes of base ``n_params + 1``), degree at most
        ``max_degree``.
    terms : list of (numpy.ndarray, int or None)
        ``(s_t, j_t)``: ``(rows,)`` factors of the view's pixels, and the index of the parameter
        the term multiplies (None: none, the degree stays). Each ``j_t`` must exceed every
        parameter index of the coefficients (the appended digit keeps the codes sorted), and the
        ``j_t`` must differ (the terms' monomials are then distinct).
    n_params, max_degree : int
        The base and the number of digits of the codes (the result's codes have the same base and
        up to ``max_degree + 1`` digits).
    products : tuple, optional
        ``(basis, alpha)``, ``(K, rows)`` and ``(T, T, K)``: the terms' products as
        ``s_t s_u = Σ_k alpha[t, u, k] basis[k]`` (checked). Given, the result keeps the
        coefficients before the expansion (:class:`~methods.symbolic.system.row_factors.RowFactors`),
        from which the field path forms its Gram matrix (:func:`~methods.symbolic.system.view_systems.dense_sum`),
        and ``a``, ``b`` are :class:`~methods.symbolic.system.pixel_matrices.FactoredColumns`: their
        products come from the factors, the copies are made only for what needs them.

    Returns
    -------
    ViewCoefficients or TiledCoefficients
        As ``coeffs``, columns sorted by their codes; both half-sample estimates (``a``, ``b``)
        are scaled alike, so the sandwich's per-pixel noise is scaled exactly.
    """
    from methods.symbolic.system.coefficients import TiledCoefficients, ViewCoefficients
    if isinstance(coeffs, TiledCoefficients):
        rows = lambda start, b: slice(start, start + b.n_rows)  # noqa: E731
        blocks = [with_factors(b, [(s[rows(start, b)], j) for s, j in terms], n_params=n_params,
                               max_degree=max_degree,
                               products=None if products is None else (products[0][:, rows(start, b)], products[1]))
                  for start, b in coeffs.blocks()]
        return TiledCoefficients(coeffs.starts, blocks, coeffs.n_rows)
    codes = np.concatenate([appended_codes(coeffs.codes, index, n_params, max_degree) for _, index in terms])
    order = np.argsort(codes, kind="stable")
    if len(np.unique(codes)) != len(codes):
        raise ValueError("with_factors: two terms give the same monomial (repeated parameter index)")
    position = np.empty(len(codes), np.int64)
    position[order] = np.arange(len(codes))                 # term t's column j goes to position[t N + j]
    columns = position.reshape(len(terms), len(coeffs.codes))
    scales = np.stack([np.asarray(scale, np.float64) for scale, _ in terms])
    # with the factors, the copies are made only where a product cannot do without them
    expand = expanded_columns if products is None else FactoredColumns
    stacked = lambda mats: None if mats is None else [expand(m, scales, columns, len(codes)) for m in mats]  # noqa: E731
    factors = None if products is None else RowFactors.of(
        coeffs.a, coeffs.b, coeffs.codes, tuple(index for _, index in terms), n_params, max_degree, scales, products)
    return ViewCoefficients(stacked(coeffs.a), stacked(coeffs.b), float(coeffs.split), codes[order],
                            factors=factors)


def lens_key(camera) -> str:
    """The key of ``camera``'s lens: its COLMAP camera id, or its view name without one."""
    cid = getattr(camera, "camera_id", None)
    return str(cid) if cid is not None else camera.name


@dataclass(frozen=True)
class Vignetting:
    """The vignetting of a run's views (module docstring).

    Attributes
    ----------
    mode : str
        ``known`` or ``estimate``.
    profile : tuple or None
        ``(a1, a2, a3)`` with ``known``.
    lenses : tuple
        ``(key, camera id or None, view names)`` of each lens (COLMAP camera) among the views,
        in order of first appearance.
    first : int
        Index of the first profile parameter (``estimate``): lens ``k``'s ``a_i`` is parameter
        ``first + 3k + i - 1``.
    """

    mode: str
    profile: tuple | None
    lenses: tuple
    first: int = 0

    @classmethod
    def of(cls, photometry, cameras, *, first: int = 0) -> "Vignetting | None":
        """From scene.yaml's ``photometry`` (None for ``none``)."""
        mode = getattr(photometry, "vignetting", "none") if photometry is not None else "none"
        if mode == "none":
            return None
        lenses: dict[str, tuple] = {}
        for cam in cameras:
            key = lens_key(cam)
            cid, names = lenses.get(key, (getattr(cam, "camera_id", None), ()))
            lenses[key] = (cid, names + (cam.name,))
        return cls(mode, photometry.vignetting_profile, tuple((k, c, n) for k, (c, n) in lenses.items()), first)

    @property
    def n_parameters(self) -> int:
        return 3 * len(self.lenses) if self.mode == "estimate" else 0

    def parameters(self) -> list:
        """The profile parameters (:class:`~framework.scene.model.Parameter`; ``segment`` below
        every gain's, ``segment_name`` ``vignetting:<camera id>``, kernel ``a1``..``a3``)."""
        from framework.scene.model import Parameter
        out = []
        if self.mode != "estimate":
            return out
        for k, (key, _, _) in enumerate(self.lenses):
            for i, name in enumerate(COEFFICIENTS):
                j = self.first + 3 * k + i
                out.append(Parameter(j, -1000 - j, VIGNETTING_PREFIX + key, name))
        return out

    def start(self, n_channels: int) -> np.ndarray:
        """``(3K, C)`` start of ``h``: 1/2, no falloff."""
        return np.full((self.n_parameters, n_channels), 0.5)

    def apply(self, coeffs, camera, *, n_params: int, max_degree: int):
        """``camera``'s coefficients (over ``n_params`` parameters, degree ``max_degree``) times
        its known falloff, or as ``c0 Γ + Σ_i c_i h_i Γ`` (degree + 1)."""
        r = pixel_radius(camera)
        if self.mode == "known":
            return with_factors(coeffs, [(falloff(r, self.profile), None)], n_params=n_params,
                                max_degree=max_degree)
        k = next(i for i, (key, _, _) in enumerate(self.lenses) if key == lens_key(camera))
        c0, *ci = estimate_terms(r)
        terms = [(c0, None)] + [(c, self.first + 3 * k + i) for i, c in enumerate(ci)]
        # the products of the terms span seven powers of r²: the Gram matrix is formed from them
        return with_factors(coeffs, terms, n_params=n_params, max_degree=max_degree, products=term_products(r))

    def report(self, estimate: np.ndarray, std: np.ndarray, correlation: dict | None = None) -> list[dict]:
        """results.json ``vignetting`` from the solve's ``h`` rows (``estimate``, ``std``: the
        full ``(n_total, C)`` arrays), one entry per lens (:func:`profile_report`)."""
        if self.mode != "estimate":
            return [{"camera": cid, "views": list(names), "estimate": list(self.profile), "std": None,
                     "known": True, "corner": float(falloff(1.0, self.profile)), "corner_std": None}
                    for _, cid, names in self.lenses]
        out = []
        for k, (key, cid, names) in enumerate(self.lenses):
            rows = slice(self.first + 3 * k, self.first + 3 * k + 3)
            labels = [f"{VIGNETTING_PREFIX}{key}/{c}" for c in COEFFICIENTS]
            corr = _sub_correlation(correlation, labels)
            out.append({"camera": cid, "views": list(names), "known": False,
                        **profile_report(estimate[rows], std[rows], corr)})
        return out


def profile_report(h: np.ndarray, h_std: np.ndarray, corr: np.ndarray | None = None, *,
                   bound: float = PROFILE_BOUND) -> dict:
    """One lens's profile from its ``(3, C)`` ``h`` and std.

    ``a_i = bound (2 h_i - 1)``, ``std(a_i) = 2 bound std(h_i)`` per channel; combined over the
    channels with inverse-variance weights ``w_c`` (equal weights where a std is missing), std
    ``Σ_c w_c std_c / Σ_c w_c`` (an upper bound on the std of the weighted mean, whatever the
    channels' correlation, by Cauchy-Schwarz). ``corner`` = ``V(1) = 1 + a1 + a2 + a3`` and its
    std from the channel-mean correlation ``corr`` (3 x 3) of the three coefficients (None
    without one).
    """
    a = bound * (2.0 * np.asarray(h, float) - 1.0)
    s = 2.0 * bound * np.asarray(h_std, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(np.isfinite(s) & (s > 0), 1.0 / s ** 2, np.nan)
    if not np.isfinite(w).all():
        w = np.ones_like(a)
    w = w / w.sum(axis=1, keepdims=True)
    est = (w * a).sum(axis=1)
    std = (w * s).sum(axis=1)
    corner = 1.0 + a.sum(axis=0)                                       # (C,)
    corner_std = None
    if corr is not None and np.isfinite(corr).all() and np.isfinite(s).all():
        per = np.sqrt(np.maximum(np.einsum("ic,ij,jc->c", s, corr, s), 0.0))
        wc = np.where(per > 0, 1.0 / np.maximum(per, 1e-300) ** 2, 1.0)
        wc = wc / wc.sum()
        corner_std = float((wc * per).sum())
        corner_value = float((wc * corner).sum())
    else:
        corner_value = float(corner.mean())
    finite = lambda v: [float(x) if np.isfinite(x) else None for x in v]   # noqa: E731
    return {"estimate": finite(est), "std": finite(std), "corner": corner_value, "corner_std": corner_std,
            "per_channel": {"estimate": [finite(row) for row in a.T], "std": [finite(row) for row in s.T]}}


def _sub_correlation(correlation: dict | None, labels: list[str]) -> np.ndarray | None:
    """The 3 x 3 block of results.json's ``correlation`` for ``labels`` (None if one is absent)."""
    if not correlation or not correlation.get("matrix"):
        return None
    index = {label: i for i, label in enumerate(correlation["labels"])}
    if not all(label in index for label in labels):
        return None
    at = [index[label] for label in labels]
    m = np.array([[np.nan if x is None else x for x in row] for row in correlation["matrix"]], float)
    return m[np.ix_(at, at)]
