"""What one solve of a polynomial pass gives: :class:`Fit`.

Built in one place per cost: :func:`methods.symbolic.fit.joint.fit_joint` (eq. 6 over every pixel),
:func:`methods.symbolic.fit.per_segment.fit_per_segment` (the estimating equations of each segment's
own pixels); the field path (:func:`methods.symbolic.fit.field.fit_field`) wraps either with what
it adds (gains, pixel weights, robust rounds).
"""
from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from methods.symbolic.system.coefficients import images_with_variance


@dataclass(frozen=True)
class Fit:
    """The estimate of one pass, its uncertainty and what the run reports of it.

    Attributes
    ----------
    estimate, std : numpy.ndarray
        ``(P, C)`` weights and standard errors; NaN where a parameter is not observable.
    observable : numpy.ndarray
        ``(P,)`` bool.
    evaluated_at : numpy.ndarray
        ``(P, C)`` the weights the images are evaluated at: the estimate, 0 where unobservable in
        the joint fit (its monomials are 0 there), the guess where the per-segment fit held a block.
    solve : SolveResult or None
        The solver's outcome (None when nothing is observable).
    iterates : list
        ``(clock, (P, C) estimate)`` of each solver evaluation, NaN where unobservable.
    correlation : dict
        results.json ``correlation`` (:func:`~methods.symbolic.uncertainty.standard_errors.correlation_extra`).
    sigma2 : list or None
        Residual variance per channel.
    std_method : str
        The formula of ``std``: ``sandwich`` or ``residual``.
    stages_s : dict
        Seconds of ``psd`` (projection of G), ``solver`` and ``uncertainty``; on the field path
        summed over its rounds, with ``field_setup`` (pixel weights, gains' and lens' coefficients),
        ``weighted_systems`` (each round's Gram system) and ``robust_weights`` (the reweighting).
    psd_skipped : tuple
        Sizes of the components of G too large for the PSD projection.
    n_monomials, gram_nnz : int
        Monomials of the solve's basis, stored entries of its G (all channels).
    images : callable
        ``images()`` -> view name -> ``(H, W, C)`` reconstruction at ``evaluated_at``.
    image_variances : callable
        ``image_variances()`` -> view name -> ``(H, W, C)`` Monte Carlo variance of each
        reconstructed pixel (from the pass's two halves; zeros without them).
    per_segment : dict or None
        ``method.cost=per_segment``: sweeps, converged, held_at_guess.
    exposure : list or None
        The field path with per-view gains: results.json ``exposure``.
    vignetting : list or None
        The field path with ``photometry: vignetting``: results.json ``vignetting``
        (:meth:`~methods.symbolic.survey.vignetting.Vignetting.report`).
    illumination : list or None
        The field path with unknown emitter scales: results.json ``illumination``
        (:meth:`~methods.symbolic.survey.illumination.Illumination.report`).
    pixel_weights, robust_weights : dict or None
        The field path: view -> ``(H, W)`` weights of the last solve; view -> the robust weights
        after the last round (a refinement pass starts from them).
    pixel_reasons : dict or None
        The field path: view -> ``(H, W)`` uint8, why each pixel left out was left out (a code of
        :data:`~framework.scene.model.EXCLUSION_REASONS`, 0: used;
        :func:`~methods.symbolic.fit.field.exclusion_reasons`).
    irls_rounds : int or None
    irls_stopped : str or None
        The field path's robust rounds and why they stopped.
    clusters : dict or None
        ``std_method`` ``cluster``: the clusters' side and the residuals' correlation length
        (:func:`~methods.symbolic.misfit.clusters.view_clusters`).
    fit_quality : dict or None
        The field path: how well the model explains each material's pixels (results.json
        ``fit_quality``, :func:`~methods.symbolic.fit.fit_quality.material_fit`), once
        :func:`with_quality` has computed it.
    spp_bias : numpy.ndarray or None
        ``method.bias=richardson``: ``(P, C)`` the finite-spp bias removed from ``estimate``
        (:mod:`methods.symbolic.loop.richardson`), NaN where not estimated.
    spp_bias_actions : numpy.ndarray or None
        ``method.bias=richardson``: ``(P, C)`` what the correction did to each weight (one of
        :data:`~methods.symbolic.loop.richardson.ACTIONS`).
    deferred_std : callable or None
        A solve asked for its estimate only (``defer_std=True``): ``std``, ``correlation`` and
        ``sigma2`` are NaN / empty and ``deferred_std()`` gives the complete Fit (:func:`with_std`).
        The field path's robust rounds and the bias correction's half refits need no standard
        error but the last round's, whose pixel scores cost as much as the solve.
    deferred_quality : callable or None
        The field path: ``deferred_quality()`` gives ``fit_quality`` (:func:`with_quality`). Only the
        last refinement pass's is reported, and a sweep over every view's pixels costs a tenth of
        a fit (bundled urban_canyon_survey: 3 of 31 s a pass): the earlier passes never make it.
    """

    estimate: np.ndarray
    std: np.ndarray
    observable: np.ndarray
    evaluated_at: np.ndarray
    solve: object | None
    iterates: list
    correlation: dict
    sigma2: list | None
    std_method: str
    stages_s: dict
    psd_skipped: tuple = ()
    n_monomials: int = 0
    gram_nnz: int = 0
    images: Callable[[], dict] = field(default=dict, repr=False)
    image_variances: Callable[[], dict] = field(default=dict, repr=False)
    per_segment: dict | None = None
    exposure: list | None = None
    vignetting: list | None = None
    illumination: list | None = None
    pixel_weights: dict | None = None
    robust_weights: dict | None = None
    pixel_reasons: dict | None = None
    irls_rounds: int | None = None
    irls_stopped: str | None = None
    clusters: dict | None = None
    spp_bias: np.ndarray | None = None
    fit_quality: dict | None = None
    spp_bias_actions: np.ndarray | None = None
    deferred_std: Callable[[], Fit] | None = field(default=None, repr=False)
    deferred_quality: Callable[[], dict] | None = field(default=None, repr=False)

    def replace(self, **changes) -> Fit:
        return dataclasses.replace(self, **changes)


def with_std(fit: Fit) -> Fit:
    """``fit`` with its standard errors: computed now where its solve deferred them."""
    return fit if fit.deferred_std is None else fit.deferred_std().replace(deferred_std=None)


def full(observable: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``(P, C)`` from the observable parameters' ``x``, NaN elsewhere."""
    out = np.full((len(observable), x.shape[1]), np.nan)
    out[observable] = x
    return out


def with_quality(fit: Fit) -> Fit:
    """``fit`` with its :attr:`Fit.deferred_quality` computed into ``fit_quality`` (itself without one)."""
    if fit.deferred_quality is None:
        return fit
    return fit.replace(fit_quality=fit.deferred_quality(), deferred_quality=None)


def images_at(result, basis, rho: np.ndarray, cameras) -> dict[str, np.ndarray]:
    """Every view's polynomial of the pass ``result`` evaluated at ρ (P, C): (H, W, C) images."""
    mu = np.stack([basis.evaluate(rho[:, c]) for c in range(rho.shape[1])])
    return {cam.name: result.image(cam.name, mu, (cam.height, cam.width)) for cam in cameras}


def fields_at(result, basis, rho: np.ndarray, cameras) -> dict[str, Callable[[], dict]]:
    """:func:`reconstruction_fields` of every view of the pass ``result`` at ρ (P, C)."""
    mu = np.stack([basis.evaluate(rho[:, c]) for c in range(rho.shape[1])])
    views = [(cam.name, result.coefficients(cam.name), (cam.height, cam.width)) for cam in cameras]
    return reconstruction_fields(views, mu, result.codes)


def reconstruction_fields(views, mu: np.ndarray, codes: np.ndarray) -> dict[str, Callable[[], dict]]:
    """``{"images": ..., "image_variances": ...}``: :class:`Fit`'s two callables for ``views``,
    ``(name, coefficients, (H, W))`` triples, at monomials ``mu`` (C, N) over ``codes``: both
    from one sweep over the views' coefficients, made on the first call."""
    both = functools.cache(lambda: images_with_variance(views, mu, codes))
    return {"images": lambda: both()[0], "image_variances": lambda: both()[1]}


class StageClock:
    """Seconds of a solve's named stages, summed: ``with clock("name"): ...`` times a block,
    :meth:`add` adds a fit's own ``stages_s``; :attr:`seconds` is the dict results.json reports
    (``solve_stages_s``)."""

    def __init__(self, seconds: dict | None = None):
        self.seconds = dict(seconds or {})

    @contextmanager
    def __call__(self, name: str):
        t = time.perf_counter()
        try:
            yield
        finally:
            self.add({name: time.perf_counter() - t})

    def add(self, stages: dict) -> None:
        for name, t in stages.items():
            self.seconds[name] = self.seconds.get(name, 0.0) + float(t)
