"""Field photographs in the symbolic fit: pixel weights, per-view exposure gains, vignetting, robust IRLS.

All four act on the per-pixel coefficients the polynomial pass stored, never on a new render.

Pixel weights
    A view's Gram system is rebuilt from its coefficients with weights ``w_p``
    (:func:`weighted_system`): the cost becomes ``Σ_p w_p (γ_p·μ - y_p)²``. Weights come from
    the scene (0 on masked, saturated, black-clipped pixels and pixels the undistortion left
    empty) times the robust weights.

Per-view exposure (``photometry: exposure: per_view``)
    A photograph is ``g_{v,c} · L_v(ρ)``: one unknown gain per view and channel multiplies every
    monomial of the view, so the pixel stays a polynomial, of degree ``N_max + 1``, in the
    parameters ``(ρ, h)``. Each non-reference view ``v`` gets a parameter ``h_v = g_v / G_MAX``
    in ``[0, 1]`` (the solver's box; :data:`GAIN_MAX`), and every monomial of its pixels is
    multiplied by ``h_v`` (:func:`with_gain`): the gains are solved jointly with ρ, exactly,
    and their standard errors come from the same sandwich as ρ's. The reference view's gains
    are 1 and fix the scale, which the data cannot (``g·L(ρ)`` = ``(g/s)·L(sρ)`` at first order).

Vignetting (``photometry: vignetting``)
    A known lens falloff multiplies each pixel's coefficients by its factor; an estimated one
    adds three parameters per COLMAP camera, appended after the gains
    (:mod:`methods.symbolic.vignetting`).

Robust weights (``method.robust``)
    Iteratively reweighted least squares: after each solve, the residuals ``r_{p,c}`` of every
    pixel are divided by a robust scale per view and channel, ``s = max(1.4826·MAD(r),
    σ_q)`` (``σ_q``: the median quantisation noise of the delivered 8/16-bit encoding, so that
    quantisation never makes an outlier), widened per pixel by the Monte Carlo variance ``v_{p,c}``
    of the pixel's own prediction (from its two half-sample estimates,
    :func:`~methods.symbolic.coefficients.predicted_with_variance`), combined over channels into
    ``t_p = sqrt(mean_c r_{p,c}² / (s_c² + v_{p,c}))``, and the pixel gets the weight ``ψ(t)/t`` of the Cauchy
    (``1/(1 + (t/2.385)²)``) or Huber (``min(1, 1.345/t)``) loss (95 % Gaussian efficiency
    each). A car or a pedestrian the model lacks leaves residuals many times the scale and is
    weighted out; the fit stops when the estimate moves less than ``tol`` between two rounds
    or after ``iterations`` rounds. Why the pixel's own variance: an unbiased Monte Carlo pass
    is heavy-tailed (a few pixels drew a rare bright path); measured against the view's scale
    alone those pixels look like outliers and were weighted out, which biased ρ by up to 15 std
    on clean linear images (tests/methods/test_consistency.py); against their own variance
    they are not.
    With ``method.consistency=auto`` a pixel that two or more other views can be compared with
    is weighed by the views' disagreement instead (:mod:`methods.symbolic.consistency`).
"""
from __future__ import annotations

import operator
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from framework.results import per_channel
from methods.symbolic.basis import MonomialBasis, code_digits, encode_digits, merge_codes
from methods.symbolic.fit import Fit, StageClock
from methods.symbolic.fit_quality import material_fit
from methods.symbolic.gram import weighted_system
from methods.symbolic.options import ROBUST_LOSSES, SymbolicOptions
from methods.symbolic.robust_scale import LEFT_OUT, cauchy_weight, pixel_variance, robust_scale
from methods.symbolic.coefficients import TiledCoefficients, ViewCoefficients, predicted, predicted_with_variance
from methods.symbolic.consistency import MIN_OTHERS, ViewPairs
from methods.symbolic.illumination import Illumination, unknown_emitters
from methods.symbolic.vignetting import Vignetting

#: ``segment_name`` of a view's gain parameter: this prefix, then the view's name
GAIN_PREFIX = "exposure:"
#: largest gain representable: h = g / GAIN_MAX lies in the solver's box [0, 1]
GAIN_MAX = 4.0
#: Huber tuning constant at 95 % efficiency for Gaussian residuals (Cauchy's: robust_scale.CAUCHY_K)
HUBER_K = 1.345


def with_gain(coeffs, *, n_params: int, max_degree: int, n_total: int, gain: int | None):
    """A view's coefficients in the basis of ``n_total`` parameters and degree ``max_degree + 1``.

    Parameters
    ----------
    coeffs : ViewCoefficients or TiledCoefficients
        Over ``n_params`` parameters of degree at most ``max_degree`` (multiset codes, base
        ``n_params + 1``, :mod:`methods.symbolic.basis`). Tiled ones are relabelled block by
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
    move = sp.csr_matrix((np.full(len(order), scale), (order, np.arange(len(order)))),
                         shape=(len(order), len(order)))
    relabel = lambda mats: None if mats is None else [sp.csr_matrix(m @ move) for m in mats]
    return ViewCoefficients(relabel(coeffs.a), relabel(coeffs.b), float(coeffs.split), codes[order])


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
        (:func:`~methods.symbolic.coefficients.predicted_with_variance`): a pixel's residual is
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


# ----------------------------------------------------------------------------------------------
# The fit
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FieldOptions:
    """What of the field path a run uses, resolved from the method's options and the scene.

    Attributes
    ----------
    weights : dict or None
        View name -> ``(H·W,)`` scene pixel weights times 0 on material boundaries (``boundary``
        pixels of a change of segment, where resampled photographs mix two materials); None:
        every pixel 1.
    floors : dict
        View name -> ``(C,)`` smallest robust scale (median quantisation noise; absent: 0).
    reference : str or None
        The reference view when gains are estimated (``exposure: per_view``), else None.
    robust : str
        ``none``, ``cauchy`` or ``huber``.
    iterations : int
        Cap on the IRLS rounds (solves); 1 without robust weights.
    tol : float
        IRLS stops when no estimate (ρ or gain) moves more than this between two rounds.
    vignetting : str
        scene.yaml ``photometry: vignetting``: ``none``, ``known`` or ``estimate``
        (:mod:`methods.symbolic.vignetting`).
    scales : int
        Emitters of unknown scale (:mod:`methods.symbolic.illumination`).
    consistency : ViewPairs or None
        The views' correspondences when pixels are weighed by the views' disagreement
        (``method.consistency``, :mod:`methods.symbolic.consistency`); None when off.
    boundary : dict or None
        View name -> ``(H·W,)`` bool: the material-boundary pixels ``weights`` leaves out (for
        the reasons of :func:`exclusion_reasons`); None without a boundary.
    """

    weights: dict | None
    floors: dict
    reference: str | None
    robust: str
    iterations: int
    tol: float
    vignetting: str = "none"
    scales: int = 0
    consistency: ViewPairs | None = None
    boundary: dict | None = None

    @property
    def active(self) -> bool:
        return (self.weights is not None or self.reference is not None or self.robust != "none"
                or self.vignetting != "none" or self.scales > 0)

    @classmethod
    def resolve(cls, options: SymbolicOptions, problem, *, boundaries: bool = True) -> "FieldOptions":
        """Resolve ``method.exposure`` (``scene``: as scene.yaml says | ``known``),
        ``method.weights`` (``scene`` | ``none``), ``method.robust`` (``auto``: Cauchy for
        photographs, i.e. images decoded from 8/16-bit files, pixel weights or per-view exposure;
        none for linear radiance), ``method.boundary`` and ``method.irls`` against ``problem``;
        ``boundaries=False`` skips the segment maps the boundary needs (the checks before a run)."""
        from framework.errors import ConfigError
        scene = problem.scene
        photometry = getattr(scene, "photometry", None)
        per_view = (options.exposure == "scene" and photometry is not None
                    and photometry.exposure == "per_view")
        reference = photometry.reference_view if per_view else None
        names = [c.name for c in problem.cameras]
        left_out = getattr(problem, "views_left_out", {}) or {}
        if per_view and reference in left_out:
            raise ConfigError(f"photometry reference_view {reference} was left out of this run: it "
                              f"{left_out[reference]}, so its gains cannot be the fit's reference; name "
                              f"another view as reference_view in scene.yaml ({', '.join(names)}), fix its "
                              "photograph or mask, or set method.exposure=known")
        if per_view and reference not in names:
            raise ConfigError(f"photometry reference_view {reference} is not among this run's views "
                              f"({', '.join(names)}): add it to views, or set method.exposure=known")
        use = options.weights == "scene" and problem.weights is not None
        weights = {n: np.asarray(w, np.float64).ravel() for n, w in problem.weights.items()} if use else None
        boundary = _boundary_width(options.boundary, problem) if boundaries else 0
        edges = segment_boundaries(problem, boundary) if boundary else None
        if edges is not None:
            weights = {n: (1.0 if weights is None else weights[n]) * ~edges[n] for n in names}
        noise = getattr(scene, "noise", None) or {}
        floors = {n: np.median(np.asarray(noise[n], float).reshape(-1, noise[n].shape[-1]), axis=0)
                  for n in names if n in noise}
        robust = options.robust
        if robust == "auto":
            robust = "cauchy" if (weights is not None or per_view or noise) else "none"
        iterations = options.irls.iterations if robust != "none" else 1
        vignetting = photometry.vignetting if photometry is not None else "none"
        compare = robust != "none" and options.consistency == "auto" and len(names) > MIN_OTHERS
        pairs = ViewPairs.of(problem) if compare and boundaries else None
        return cls(weights, floors, reference, robust, iterations, options.irls.tol, vignetting,
                   len(unknown_emitters(scene)), pairs, edges)

    def describe(self, fit: Fit) -> dict:
        """``extras["field"]``: what the fit did (JSON-able)."""
        return {"exposure": "per_view" if self.reference is not None else "known",
                "reference_view": self.reference, "robust": self.robust,
                "scene_weights": self.weights is not None, "irls_rounds": fit.irls_rounds,
                "irls_stopped": fit.irls_stopped, "vignetting": self.vignetting, "unknown_scales": self.scales,
                "consistency": self.consistency is not None}


def _boundary_width(value: int | str, problem) -> int:
    """``method.boundary`` in pixels: ``auto`` is 1 when some view was resampled from a distorted
    camera, else 0. The pass renders such a view's pixels over the interpolation's footprint, so
    both sides of an edge are mixed as in the photograph; leaving the edge's pixels out still
    helped, measured (the field scene's window ρ_d error 0.011 against 0.016 without)."""
    if value != "auto":
        return int(value)
    return int(any(getattr(c, "distortion", None) is not None for c in problem.cameras))


def segment_boundaries(problem, width: int) -> dict[str, np.ndarray]:
    """View name -> ``(H·W,)`` bool: pixels within ``width`` pixels (a square) of a pixel whose
    centre sees another segment (or the sky)."""
    from framework.render.mitsuba_scene import segment_maps
    maps = segment_maps(problem.scene, problem.cameras)
    out = {}
    for cam in problem.cameras:
        seg = maps[cam.name]
        edge = np.zeros(seg.shape, bool)
        edge[:, 1:] |= seg[:, 1:] != seg[:, :-1]
        edge[:, :-1] |= seg[:, 1:] != seg[:, :-1]
        edge[1:] |= seg[1:] != seg[:-1]
        edge[:-1] |= seg[1:] != seg[:-1]
        grown = edge.copy()
        for _ in range(width - 1):
            grown[:, 1:] |= grown[:, :-1].copy()
            grown[:, :-1] |= grown[:, 1:].copy()
            grown[1:] |= grown[:-1].copy()
            grown[:-1] |= grown[1:].copy()
        out[cam.name] = grown.ravel()
    return out


@dataclass
class _View:
    name: str
    shape: tuple[int, int]
    coeffs: object               # ViewCoefficients or Coefficients over the solve's parameters
    y: np.ndarray                # (n, C)
    scene_w: np.ndarray | None   # (n,)
    gain: int | None             # index of its gain parameter
    robust_w: np.ndarray | None = None
    compared: np.ndarray | None = None   # (n,) bool: robust_w is the views' agreement there

    @property
    def weights(self) -> np.ndarray | None:
        if self.robust_w is None:
            return self.scene_w
        return self.robust_w if self.scene_w is None else self.scene_w * self.robust_w


def field_views(result, problem, params, x0: np.ndarray, options: FieldOptions
                ) -> tuple[list[_View], list, np.ndarray, Vignetting | None, Illumination | None]:
    """The views of the fit over ``(ρ, h)``, the scale, gain and profile parameters and the extended start.

    Returns ``(views, extra_parameters, x0, vignetting, illumination)``: one :class:`_View` per
    camera; a :class:`~framework.scene.model.Parameter` per unknown emitter scale
    (:meth:`Illumination.parameters`; the pass's coefficients are already over them), per gain
    (``segment`` -1 - j, kernel ``gain``, ``segment_name`` ``exposure:<view>``), then per lens the
    three profile parameters with ``vignetting: estimate`` (:meth:`Vignetting.parameters`); ``x0``
    with the scales' start (the declared light), each view's gain guess (:func:`gain_guess` at
    ``x0``, over ``GAIN_MAX``) and the profiles' start (no falloff) appended; the run's
    :class:`~methods.symbolic.vignetting.Vignetting` and
    :class:`~methods.symbolic.illumination.Illumination` (None without).
    """
    from framework.scene.model import Parameter
    from methods.symbolic.basis import MonomialBasis
    P, C = len(params), problem.n_channels
    light = Illumination.of(problem.scene, first=P)
    Q = P + (light.n_parameters if light is not None else 0)            # ρ and the scales: the pass's variables
    N = problem.settings.max_bounces + (1 if light is not None else 0)  # and its degree
    gained = [c.name for c in problem.cameras if options.reference is not None and c.name != options.reference]
    gains = [Parameter(Q + j, -1 - j, GAIN_PREFIX + name, "gain") for j, name in enumerate(gained)]
    lens = Vignetting.of(problem.scene.photometry, problem.cameras, first=Q + len(gained)) \
        if options.vignetting != "none" else None
    extra = (light.parameters() if light is not None else []) + gains + (lens.parameters() if lens is not None else [])
    if light is not None:
        x0 = np.vstack([x0, light.start(C)])
    base = MonomialBasis(Q, N, result.codes)
    mu0 = np.stack([base.evaluate(x0[:, c]) for c in range(C)])
    views, h0 = [], []
    for cam in problem.cameras:
        coeffs = result.coefficients(cam.name)
        if light is not None:                               # per unit s -> per unit h (the solver's box)
            coeffs = light.to_box(coeffs, max_degree=N)
        y = np.asarray(problem.observed[cam.name], np.float64).reshape(-1, C)
        w = options.weights.get(cam.name) if options.weights is not None else None
        gain = Q + gained.index(cam.name) if cam.name in gained else None
        if lens is not None and lens.mode == "known":      # before the gain guess: the gain of V·L
            coeffs = lens.apply(coeffs, cam, n_params=Q, max_degree=N)
        if gain is not None:
            h0.append(gain_guess(coeffs, y, w, mu0, result.codes) / GAIN_MAX)
        if len(extra) > Q - P:
            coeffs = with_gain(coeffs, n_params=Q, max_degree=N, n_total=P + len(extra), gain=gain)
        if lens is not None and lens.mode == "estimate":
            coeffs = lens.apply(coeffs, cam, n_params=P + len(extra), max_degree=N + (gain is not None))
        views.append(_View(cam.name, (cam.height, cam.width), coeffs, y, w, gain))
    starts = [x0] + [h[None] for h in h0] + ([lens.start(C)] if lens is not None and lens.n_parameters else [])
    return views, extra, np.vstack(starts), lens, light


def fit_field(result, params, x0: np.ndarray, problem, options: FieldOptions, solve, *,
              start: dict | None = None) -> Fit:
    """Fit ρ (and the gains) to the weighted pixels, reweighting them (IRLS) from the stored
    coefficients; the module docstring gives the model.

    ``solve(system, basis, parameters, x0, problem, views=, groups=)`` is the method's solve (the
    joint or the per-segment fit and the sandwich std). Returns its :class:`Fit` restricted to ρ's
    ``P`` rows, with ``exposure``, ``pixel_weights``, ``robust_weights``, ``irls_rounds``,
    ``irls_stopped``, the images and every round's iterates; ``start``: the robust weights a
    previous pass ended with (a refinement pass starts from them instead of a plain L2 round that
    outliers drag).
    """
    from functools import reduce

    from methods._common import segment_groups
    from methods.symbolic.basis import MonomialBasis
    P, C = len(params), problem.n_channels
    clock = StageClock()
    with clock("field_setup"):
        views, extra, x, lens, light = field_views(result, problem, params, x0, options)
    gains = [p for p in extra if p.kernel == "gain"]
    every = list(params) + extra
    degree = (problem.settings.max_bounces + (1 if light is not None else 0) + (1 if gains else 0)
              + (1 if lens is not None and lens.n_parameters else 0))
    if start and options.robust != "none":
        for v in views:
            v.robust_w = start.get(v.name)
    elif options.consistency is not None:    # the high-breakdown start: the views' disagreement at x
        codes = merge_codes([0], *(b.codes for v in views for _, b in v.coeffs.blocks()))
        mu = np.stack([MonomialBasis(len(every), degree, codes).evaluate(x[:, c]) for c in range(C)])
        with clock("robust_weights"):
            _reweight(views, mu, codes, options, per_pixel=False)
    iterates, stopped, fit = [], "single solve", None
    for round_ in range(options.iterations):
        with clock("weighted_systems"):
            system = reduce(operator.iadd, (weighted_system(v.coeffs, v.y, v.weights) for v in views))
        basis = MonomialBasis(len(every), degree, system.codes)
        used = [v.weights for v in views]
        fit = solve(system, basis, every, x, problem, groups=segment_groups(params),
                    views=lambda: ((v.coeffs, v.y, w) for v, w in zip(views, used)))
        clock.add(fit.stages_s)             # every round's solve, not only the last one's
        iterates += fit.iterates
        moved = np.nanmax(np.abs(fit.estimate - x)) if np.isfinite(fit.estimate).any() else 0.0
        x = np.where(np.isnan(fit.estimate), x, fit.estimate)
        if options.robust == "none":
            break
        if round_ and moved < options.tol:
            stopped = f"converged (moved {moved:.2g} < {options.tol:g})"
            break
        stopped = f"{options.iterations} rounds"
        with clock("robust_weights"):
            mu = np.stack([basis.evaluate(x[:, c]) for c in range(C)])
            _reweight(views, mu, system.codes, options)
    with clock("fit_quality"):        # how well the model explains each material (no ground truth)
        from framework.render.mitsuba_scene import segment_maps
        mu = np.stack([basis.evaluate(fit.evaluated_at[:, c]) for c in range(C)])
        quality = material_fit(problem, views, mu, system.codes, segment_maps(problem.scene, problem.cameras),
                               at=(basis, fit.evaluated_at, params, fit.std))
    with clock("field_outputs"):
        out = _field_outputs(fit, views, used, basis, system, gains, P, C, round_ + 1, stopped, iterates)
        out = out.replace(pixel_reasons=exclusion_reasons(problem, options, views), stages_s=clock.seconds,
                          fit_quality=quality)
    if light is not None:
        out = out.replace(illumination=light.report(fit.estimate, fit.std))
    return out if lens is None else out.replace(vignetting=lens.report(fit.estimate, fit.std, fit.correlation))


def _reweight(views, mu: np.ndarray, codes: np.ndarray, options: FieldOptions, *, per_pixel: bool = True) -> None:
    """Each view's robust weights at the monomials ``mu``: the views' disagreement
    (:mod:`methods.symbolic.consistency`) where a pixel has other views to compare with, else the
    per-pixel robust weights (``per_pixel=False``: 1 there, the first solve's start)."""
    pred, var = {}, {}
    for v in views:
        pred[v.name], raw = predicted_with_variance(v.coeffs, mu, codes)
        var[v.name] = pixel_variance(raw, v.shape)
    usable = {v.name: np.ones(len(v.y), bool) if v.scene_w is None else v.scene_w > 0 for v in views}
    agree = options.consistency.weights({v.name: v.y for v in views}, pred, usable, var) \
        if options.consistency is not None else {}
    for v in views:
        w = robust_weights(pred[v.name] - v.y, usable[v.name], loss=options.robust,
                           floor=options.floors.get(v.name, 0.0), variance=var[v.name]) \
            if per_pixel else np.ones(len(v.y))
        v.compared = ~np.isnan(agree[v.name]) if v.name in agree else None
        if v.compared is not None:
            w = np.where(v.compared, agree[v.name], w)
        v.robust_w = w


def exclusion_reasons(problem, options: FieldOptions, views) -> dict[str, np.ndarray]:
    """View name -> ``(H, W)`` uint8 code of :data:`~framework.scene.model.EXCLUSION_REASONS`
    for each pixel the fit left out, the first that applies: the scene's reason (mask, saturated,
    outside), a material boundary, then a robust weight below :data:`LEFT_OUT` set by the views'
    disagreement (inconsistent) or by the pixel's own residual (outlier); 0 where used."""
    from framework.scene.model import EXCLUSION_REASONS
    code = {r: i for i, r in enumerate(EXCLUSION_REASONS)}
    scene_reasons = getattr(problem.scene, "excluded", None) or {}
    out = {}
    for v in views:
        n = len(v.y)
        base = scene_reasons.get(v.name)
        r = np.zeros(n, np.uint8) if base is None else np.asarray(base, np.uint8).ravel().copy()
        free = r == 0
        if options.boundary is not None:
            edge = free & options.boundary[v.name]
            r[edge], free = code["boundary"], free & ~edge
        if v.robust_w is not None:
            low = free & (v.robust_w < LEFT_OUT)
            compared = v.compared if v.compared is not None else np.zeros(n, bool)
            r[low & compared] = code["inconsistent"]
            r[low & ~compared] = code["outlier"]
        out[v.name] = r.reshape(v.shape)
    return out


def _field_outputs(fit: Fit, views, used, basis, system, gains, P, C, rounds, stopped, iterates) -> Fit:
    """The fit of ρ from the extended solve (see :func:`fit_field`)."""
    est, std = fit.estimate, fit.std
    exposure = None
    if gains:
        names = {p.index: p.segment_name.removeprefix(GAIN_PREFIX) for p in gains}
        exposure = [{"view": v.name, "reference": v.gain is None,
                     "estimate": [1.0] * C if v.gain is None else per_channel(GAIN_MAX * est[v.gain]),
                     "std": None if v.gain is None else per_channel(GAIN_MAX * std[v.gain])}
                    for v in views if v.gain is None or v.gain in names]
    rho = fit.evaluated_at       # the per-segment fit holds unseen blocks at their guess
    mu = np.stack([basis.evaluate(rho[:, c]) for c in range(C)])
    return fit.replace(
        estimate=est[:P], evaluated_at=rho[:P], std=std[:P], observable=fit.observable[:P], exposure=exposure,
        iterates=[(at, x[:P]) for at, x in iterates], irls_rounds=rounds, irls_stopped=stopped,
        n_monomials=basis.size, gram_nnz=system.nnz, robust_weights={v.name: v.robust_w for v in views},
        pixel_weights={v.name: (np.ones(len(v.y)) if w is None else w).reshape(v.shape).astype(np.float32)
                       for v, w in zip(views, used)},
        images=lambda: {v.name: predicted(v.coeffs, mu, system.codes).reshape(*v.shape, C).astype(np.float32)
                        for v in views})
