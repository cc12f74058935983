"""Field photographs in the symbolic fit: pixel weights, per-view exposure gains, vignetting, robust IRLS.

All four act on the per-pixel coefficients the polynomial pass stored, never on a new render.

Pixel weights
    A view's Gram system is rebuilt from its coefficients with weights ``w_p``
    (:func:`~methods.symbolic.system.view_systems.weighted_system`): the cost becomes
    ``Σ_p w_p (γ_p·μ - y_p)²``. Weights come from
    the scene (0 on masked, saturated, black-clipped pixels and pixels the undistortion left
    empty) times the robust weights.

Per-view exposure (``photometry: exposure: per_view``)
    One unknown gain per view and channel multiplies every monomial of the view: one more
    parameter per non-reference view, solved jointly with ρ (:mod:`methods.symbolic.survey.exposure`).

Vignetting (``photometry: vignetting``)
    A known lens falloff multiplies each pixel's coefficients by its factor; an estimated one
    adds three parameters per COLMAP camera, appended after the gains
    (:mod:`methods.symbolic.survey.vignetting`).

Robust weights (``method.robust``)
    Iteratively reweighted least squares: after each solve every pixel gets the weight of the
    Cauchy or Huber loss at its residual, measured against the view's robust scale widened by the
    pixel's own Monte Carlo variance (:mod:`methods.symbolic.misfit.robust_weights`); the fit
    stops when the estimate moves less than ``tol`` between two rounds or after ``iterations``
    rounds. With ``method.consistency=auto`` a pixel that two or more other views can be compared
    with is weighed by the views' disagreement instead (:mod:`methods.symbolic.misfit.consistency`).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from framework.results import per_channel
from framework.threads import run_threads
from methods.symbolic.fit.fit import Fit, StageClock, reconstruction_fields, with_std
from methods.symbolic.fit.fit_quality import material_fit
from methods.symbolic.misfit.consistency import MIN_OTHERS, ViewPairs
from methods.symbolic.misfit.robust_scale import LEFT_OUT, pixel_variance
from methods.symbolic.misfit.robust_weights import robust_weights
from methods.symbolic.options import SymbolicOptions
from methods.symbolic.survey.exposure import GAIN_MAX, GAIN_PREFIX, gain_guess, with_gain
from methods.symbolic.survey.illumination import Illumination
from methods.symbolic.survey.vignetting import Vignetting
from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.coefficients import predicted_with_variance
from methods.symbolic.system.emitter_groups import unknown_emitters
from methods.symbolic.system.view_systems import summed_views
from methods.symbolic.trace.monomial_codes import merge_codes


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
        (:mod:`methods.symbolic.survey.vignetting`).
    scales : int
        Emitters of unknown scale (:mod:`methods.symbolic.survey.illumination`).
    consistency : ViewPairs or None
        The views' correspondences when pixels are weighed by the views' disagreement
        (``method.consistency``, :mod:`methods.symbolic.misfit.consistency`); None when off.
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
        """Whether the fit takes the field path (:func:`field_path_reasons`)."""
        return bool(field_path_reasons(weights=self.weights is not None, gains=self.reference is not None,
                                       robust=self.robust, vignetting=self.vignetting, scales=self.scales))

    @classmethod
    def resolve(cls, options: SymbolicOptions, problem, *, boundaries: bool = True) -> "FieldOptions":
        """Apply ``method.exposure`` (``scene``: as scene.yaml says | ``known``),
        ``method.weights`` (``scene`` | ``none``), ``method.robust``, ``method.boundary`` and
        ``method.irls`` to ``problem``; ``options`` has its ``auto`` values decided
        (:func:`methods.symbolic.loop.resolved.resolve`). ``boundaries=False`` skips the segment maps
        the boundary needs (the checks before a run)."""
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
        if "auto" in (options.robust, options.boundary):
            raise ValueError("FieldOptions.resolve takes resolved options (methods.symbolic.loop.resolved)")
        boundary = int(options.boundary) if boundaries else 0
        edges = segment_boundaries(problem, boundary) if boundary else None
        if edges is not None:
            weights = {n: (1.0 if weights is None else weights[n]) * ~edges[n] for n in names}
        noise = getattr(scene, "noise", None) or {}
        floors = {n: np.median(np.asarray(noise[n], float).reshape(-1, noise[n].shape[-1]), axis=0)
                  for n in names if n in noise}
        robust = options.robust
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


def field_path_reasons(*, weights: bool, gains: bool, robust: str, vignetting: str, scales: int) -> list[str]:
    """What puts a fit on the field path, each a short phrase; empty when nothing does (the pass's
    own system is then solved). ``weights``: pixel weights (scene or material-boundary ones);
    ``gains``: per-view gains estimated; ``robust``: ``method.robust``; ``vignetting``: scene.yaml's
    ``photometry: vignetting``; ``scales``: emitters of unknown scale."""
    return [why for why, on in (("pixel weights", weights), ("per-view gains", gains),
                                ("robust rounds", robust != "none"),
                                ("a lens to estimate or apply", vignetting != "none"),
                                ("unknown light scales", scales > 0)) if on]


def field_views(result, problem, params, x0: np.ndarray, options: FieldOptions
                ) -> tuple[list[_View], list, np.ndarray, Vignetting | None, Illumination | None]:
    """The views of the fit over ``(ρ, h)``, the scale, gain and profile parameters and the extended start.

    Returns ``(views, extra_parameters, x0, vignetting, illumination)``: one :class:`_View` per
    camera; a :class:`~framework.scene.model.Parameter` per unknown emitter scale
    (:meth:`Illumination.parameters`; the pass's coefficients are already over them), per gain
    (``segment`` -1 - j, kernel ``gain``, ``segment_name`` ``exposure:<view>``), then per lens the
    three profile parameters with ``vignetting: estimate`` (:meth:`Vignetting.parameters`); ``x0``
    with the scales' start (the declared light), each view's gain guess
    (:func:`~methods.symbolic.survey.exposure.gain_guess`
    at ``x0``, over ``GAIN_MAX``) and the profiles' start (no falloff) appended; the run's
    :class:`~methods.symbolic.survey.vignetting.Vignetting` and
    :class:`~methods.symbolic.survey.illumination.Illumination` (None without).
    """
    from framework.scene.model import Parameter
    from methods.symbolic.system.basis import MonomialBasis
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

    def view(cam) -> tuple[_View, np.ndarray | None]:
        coeffs = result.coefficients(cam.name)
        if light is not None:                               # per unit s -> per unit h (the solver's box)
            coeffs = light.to_box(coeffs, max_degree=N)
        y = np.asarray(problem.observed[cam.name], np.float64).reshape(-1, C)
        w = options.weights.get(cam.name) if options.weights is not None else None
        gain = Q + gained.index(cam.name) if cam.name in gained else None
        if lens is not None and lens.mode == "known":      # before the gain guess: the gain of V·L
            coeffs = lens.apply(coeffs, cam, n_params=Q, max_degree=N)
        h = None if gain is None else gain_guess(coeffs, y, w, mu0, result.codes) / GAIN_MAX
        if len(extra) > Q - P:
            coeffs = with_gain(coeffs, n_params=Q, max_degree=N, n_total=P + len(extra), gain=gain)
        if lens is not None and lens.mode == "estimate":
            coeffs = lens.apply(coeffs, cam, n_params=P + len(extra), max_degree=N + (gain is not None))
        return _View(cam.name, (cam.height, cam.width), coeffs, y, w, gain), h

    # the views side by side: their sparse relabelling and sorting release the GIL (bundled
    # urban_canyon_survey, 2026-12-05: 5.4 s a fit in turn, 3.3 s on two threads)
    made = run_threads([lambda cam=cam: view(cam) for cam in problem.cameras])
    views, h0 = [v for v, _ in made], [h for _, h in made if h is not None]
    starts = [x0] + [h[None] for h in h0] + ([lens.start(C)] if lens is not None and lens.n_parameters else [])
    return views, extra, np.vstack(starts), lens, light


def fit_field(result, params, x0: np.ndarray, problem, options: FieldOptions, solve, *,
              start: dict | None = None, estimate_only: bool = False) -> Fit:
    """Fit ρ (and the gains) to the weighted pixels, reweighting them (IRLS) from the stored
    coefficients; the module docstring gives the model.

    ``solve(system, basis, parameters, x0, problem, views=, groups=)`` is the method's solve (the
    joint or the per-segment fit and the sandwich std). Returns its :class:`Fit` restricted to ρ's
    ``P`` rows, with ``exposure``, ``pixel_weights``, ``robust_weights``, ``irls_rounds``,
    ``irls_stopped``, the images and every round's iterates; ``start``: the robust weights a
    previous pass ended with (a refinement pass starts from them instead of a plain L2 round that
    outliers drag); ``estimate_only``: the rounds' estimate alone, without standard errors, fit
    quality and excluded pixels' reasons (the bias correction's half refits). Each round's
    standard errors are deferred (:attr:`Fit.deferred_std`): only the last round's are computed.
    """
    from methods._common import segment_groups
    from methods.symbolic.system.basis import MonomialBasis
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
            system = summed_views((v.coeffs, v.y, v.weights) for v in views)
        basis = MonomialBasis(len(every), degree, system.codes)
        used = [v.weights for v in views]
        # late binding: the deferred std reads the last round's ``used``, the weights of its solve
        fit = solve(system, basis, every, x, problem, groups=segment_groups(params), defer_std=True,
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
    if estimate_only:
        return _field_outputs(fit, views, used, basis, system, gains, P, C, round_ + 1, stopped, iterates
                              ).replace(stages_s=clock.seconds)
    with clock("uncertainty"):
        fit = with_std(fit)
    with clock("field_outputs"):
        out = _field_outputs(fit, views, used, basis, system, gains, P, C, round_ + 1, stopped, iterates)
        out = out.replace(pixel_reasons=exclusion_reasons(problem, options, views), stages_s=clock.seconds,
                          deferred_quality=_quality(problem, views, basis, system.codes, fit, params))
    if light is not None:
        out = out.replace(illumination=light.report(fit.estimate, fit.std))
    return out if lens is None else out.replace(vignetting=lens.report(fit.estimate, fit.std, fit.correlation))


def _quality(problem, views, basis, codes: np.ndarray, fit: Fit, params) -> Callable[[], dict]:
    """How well the model explains each material at ``fit`` (no ground truth), when called:
    :attr:`Fit.deferred_quality` (:func:`~methods.symbolic.fit.fit.with_quality`)."""
    def quality() -> dict:
        from framework.render.mitsuba_scene import segment_maps
        mu = np.stack([basis.evaluate(fit.evaluated_at[:, c]) for c in range(fit.evaluated_at.shape[1])])
        return material_fit(problem, views, mu, codes, segment_maps(problem.scene, problem.cameras),
                            at=(basis, fit.evaluated_at, params, fit.std))
    return quality


def _reweight(views, mu: np.ndarray, codes: np.ndarray, options: FieldOptions, *, per_pixel: bool = True) -> None:
    """Each view's robust weights at the monomials ``mu``: the views' disagreement
    (:mod:`methods.symbolic.misfit.consistency`) where a pixel has other views to compare with, else the
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
        **reconstruction_fields([(v.name, v.coeffs, v.shape) for v in views], mu, system.codes))
