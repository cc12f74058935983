"""Every ``auto`` of ``method=symbolic``'s options turned into its value for one problem, and why.

The one place where an ``auto`` is decided: :func:`resolve` reads what the rules need from the
problem (:class:`Facts`: photographs or rendered observations, pixel weights, per-view gains,
quantised images, distorted cameras, the lens, unknown light, spp), :func:`resolved` applies the
rules below and says why, and results.json records each decision (``options_resolved``: per option
that was ``auto``, its ``value`` and ``why``). The stages below the loop receive options with no
``auto`` left (``solver.starts`` excepted: it is decided per parameter block by the solve).

Rules, in the order they depend on each other:

``boundary``
    1 when some view was resampled from a distorted camera (its edge pixels mix two materials as
    the interpolation did), else 0. The pass renders such a view over the interpolation's
    footprint, so both sides of an edge mix as in the photograph; leaving the edge's pixels out
    still helped (measured on the field scene: the window's ρ_d error 0.011, 0.016 without).
``robust``
    ``cauchy`` for photographs that carry pixel weights (scene masks and clipped pixels, or the
    ``boundary`` pixels), per-view gains or quantisation (8/16-bit files); ``none`` for linear
    radiance.
``consistency``
    stays ``auto`` (pixels weighed by the views' disagreement) with robust reweighting and more
    than :data:`~methods.symbolic.misfit.consistency.MIN_OTHERS` views, else ``none``.
``std``
    ``cluster`` for photographs (a scene's ``images/``, any encoding) with the joint cost: their
    residuals are spatially correlated (resampling, compression, texture, misregistration);
    ``sandwich`` for observations the run renders itself, whose residuals are independent.
``align``
    ``rotation`` for photographs with ``refine`` >= 1 (a surveyed pose is a fraction of a pixel
    off); ``none`` for rendered observations (exact poses) or without a further pass.
``std_device``
    ``device`` on a ``cuda_*`` variant (the std's products as kernels on the GPU), ``host`` on an
    ``llvm_*`` one, where the std with scipy's products took 0.36-0.73 of its time through Dr.Jit
    (the two give the same values; docs/design-notes.md).
``bias``
    ``richardson`` on the field path (pixel weights, gains, robust rounds, a lens, unknown light:
    a solve non-linear in the pass's noisy coefficients) when ``spp`` is a multiple of 4 and
    ``gram`` is ``cross``; else ``none`` (a plain L2 solve is as near linear in them as a
    rendered scene's, and the correction's own noise would outweigh the bias it removes).
"""
from __future__ import annotations

import dataclasses

from framework.render.backend import jit_backend
from methods.symbolic.fit.field import field_path_reasons
from methods.symbolic.fit.solve import AUTO_STARTS, AUTO_STARTS_MAX_PARAMS
from methods.symbolic.misfit.consistency import MIN_OTHERS
from methods.symbolic.options import SymbolicOptions
from methods.symbolic.system.emitter_groups import unknown_emitters


@dataclasses.dataclass(frozen=True)
class Facts:
    """What the ``auto`` rules read from a problem (:meth:`of`)."""

    photographs: bool      #: the scene delivers ``images/`` (any encoding)
    weights: bool          #: the scene marks pixels (masks, clipping) and ``method.weights=scene``
    per_view: bool         #: per-view exposure gains are estimated (``photometry exposure: per_view``)
    quantised: bool        #: images decoded from 8/16-bit files (a quantisation noise floor)
    distorted: bool        #: some view was resampled from a distorted camera
    vignetting: str        #: ``photometry vignetting``: ``none``, ``known`` or ``estimate``
    scales: int            #: emitters of unknown scale
    spp: int               #: ``render.spp``
    views: int             #: views fitted
    backend: str = "llvm"  #: the run's Dr.Jit backend (``cuda`` or ``llvm``)

    @classmethod
    def of(cls, options: SymbolicOptions, problem) -> "Facts":
        scene = problem.scene
        photometry = getattr(scene, "photometry", None)
        return cls(photographs=scene.images is not None,
                   weights=options.weights == "scene" and problem.weights is not None,
                   per_view=(options.exposure == "scene" and photometry is not None
                             and photometry.exposure == "per_view"),
                   quantised=bool(getattr(scene, "noise", None)),
                   distorted=any(getattr(c, "distortion", None) is not None for c in problem.cameras),
                   vignetting=photometry.vignetting if photometry is not None else "none",
                   scales=len(unknown_emitters(scene)), spp=int(problem.settings.spp),
                   views=len(problem.cameras), backend=jit_backend(problem.settings.variant))


@dataclasses.dataclass(frozen=True)
class Resolved:
    """Options with their ``auto`` values decided, and results.json's ``options_resolved``."""

    options: SymbolicOptions
    why: dict            #: option -> {"value": ..., "why": str}, for each option given as ``auto``


def resolve(options: SymbolicOptions, problem) -> Resolved:
    """``options`` for ``problem`` with every ``auto`` decided (module docstring)."""
    return resolved(options, Facts.of(options, problem))


def resolved(options: SymbolicOptions, facts: Facts) -> Resolved:
    """The rules of the module docstring applied to ``facts``; an option not ``auto`` is kept."""
    why, values = {}, {}

    def decide(key: str, value, reason: str):
        if getattr(options, key) != "auto":
            return getattr(options, key)
        why[key], values[key] = {"value": value, "why": reason}, value
        return value

    seen = "photographs (the scene's images/)" if facts.photographs else "observations rendered by the run"
    boundary = decide("boundary", int(facts.distorted),
                      "a view resampled from a distorted camera: its edge pixels mix two materials"
                      if facts.distorted else "no view was resampled from a distorted camera")
    marks = [w for w, on in (("pixel weights", facts.weights), ("material-boundary pixels", boundary > 0),
                             ("per-view gains", facts.per_view), ("8/16-bit images", facts.quantised)) if on]
    robust = decide("robust", "cauchy" if marks else "none",
                    f"photographs with {', '.join(marks)}" if marks else "linear radiance without pixel weights")
    decide("std", "cluster" if facts.photographs and options.cost == "joint" else "sandwich",
           f"{seen}, cost {options.cost}: " + ("residuals correlated between neighbouring pixels"
                                               if facts.photographs and options.cost == "joint"
                                               else "residuals independent between pixels" if not facts.photographs
                                               else "the cluster std is the joint cost's"))
    decide("align", "rotation" if facts.photographs and options.refine >= 1 else "none",
           f"{seen}, refine {options.refine}: " + ("a surveyed pose is a fraction of a pixel off"
                                                   if facts.photographs and options.refine >= 1
                                                   else "no further pass to register before" if facts.photographs
                                                   else "the run's own poses are exact"))
    gpu = facts.backend == "cuda"
    decide("std_device", "device" if gpu else "host",
           "a cuda_* variant: the scores' products on the GPU, where the coefficients' sums are kernels" if gpu
           else "an llvm_* variant: scipy's products on the host are faster than Dr.Jit's on the CPU")
    compare = robust != "none" and facts.views > MIN_OTHERS
    decide("consistency", "auto" if compare else "none",
           f"robust reweighting over {facts.views} views: a pixel two other views see is weighed by their "
           "disagreement" if compare else f"robust {robust}, {facts.views} view(s): no views to compare")
    parts = field_reasons(facts, boundary=boundary, robust=robust)
    field = bool(parts)
    ok = facts.spp % 4 == 0 and options.gram == "cross"
    decide("bias", "richardson" if field and ok else "none",
           (f"the field path ({', '.join(parts)}): its solve is non-linear in the pass's noisy coefficients" if field
            else "a plain L2 solve, near linear in the pass's coefficients")
           + ("" if ok or not field else f"; but render.spp={facts.spp} is not a multiple of 4 or gram is not cross"))
    if options.solver.starts == "auto":
        why["solver.starts"] = {"value": "auto", "why": f"per parameter block: {AUTO_STARTS} starts for a block of "
                                                        f"at most {AUTO_STARTS_MAX_PARAMS} parameters, 1 above"}
    return Resolved(dataclasses.replace(options, **values), why)


def field_reasons(facts: Facts, *, boundary: int, robust: str) -> list[str]:
    """What puts the fit on the field path (:func:`~methods.symbolic.fit.field.field_path_reasons`
    of these facts, ahead of the :class:`~methods.symbolic.fit.field.FieldOptions` they build)."""
    return field_path_reasons(weights=bool(facts.weights or boundary > 0), gains=facts.per_view, robust=robust,
                              vignetting=facts.vignetting, scales=facts.scales)
