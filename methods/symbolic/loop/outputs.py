"""The symbolic method's :class:`~framework.registry.MethodResult`: estimates, std and the extras
results.json reports (docs/results.md, "method-specific keys")."""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from framework.registry import MethodResult
from framework.relight import relight_outputs
from methods._common import Trace
from methods.symbolic.fit.fit_quality import floored_std, poor_parameters
from methods.symbolic.loop.refinement import Passes
from methods.symbolic.options import SymbolicOptions
from methods.symbolic.uncertainty.standard_errors import ill_determined

def method_result(passes: Passes, problem, params, guess: np.ndarray, options: SymbolicOptions, *,
                  started: float, trace: Trace) -> MethodResult:
    """The run's result from its passes; relit images when ``options.relight.enabled``."""
    fit, sol = passes.fit, passes.fit.solve
    poor, why = poor_parameters(fit.fit_quality, params)        # a material the model does not explain
    # a material whose own pixels pull its weights beyond their noise: the reported std covers the
    # pull. Here, not in the passes: their stop test compares two passes' Monte Carlo noise, which
    # the sandwich std measures and the pull does not
    std, floors = (fit.std, {}) if fit.std is None else floored_std(fit.fit_quality, params, fit.std)
    stages = dict(passes.stages_s)
    extras = {"n_monomials": fit.n_monomials, "gram_nnz": fit.gram_nnz,
              "parameter_blocks": len(sol.blocks) if sol else 0, "psd_skipped_components": list(fit.psd_skipped),
              "solver_evaluations": sol.n_evals if sol else 0,
              "solver_evaluations_from_guess": sol.guess_evals if sol else 0,
              "initial_guess": guess.tolist(), "views_from_cache": passes.from_cache,
              "correlation": fit.correlation, "residual_variance": fit.sigma2, "std_method": fit.std_method,
              "ill_determined": (ill_determined(std, fit.observable) | poor).tolist(),
              "executor": problem.settings.executor.name,
              "solve_stages_s": stages, "refine_moves": passes.moves, "refine_stopped": passes.stopped,
              "cost": options.cost, "options_resolved": passes.resolved}
    if fit.spp_bias is not None:
        extras["spp_bias"] = {"method": "richardson", "spp": int(problem.settings.spp),
                              "bias": np.where(np.isfinite(fit.spp_bias), fit.spp_bias, None).tolist(),
                              "correction": fit.spp_bias_actions.tolist()}
    if fit.fit_quality is not None:
        extras["fit_quality"] = {name: {**entry, **({"std_scale": floors[name]} if name in floors else {})}
                                 for name, entry in fit.fit_quality.items()}
        extras["ill_determined_why"] = why
    if fit.clusters is not None:
        extras["std_clusters"] = fit.clusters
    if fit.per_segment is not None:
        extras["per_segment"] = fit.per_segment
    if passes.field.active:
        extras["field"] = passes.field.describe(fit)
    if fit.exposure is not None:
        extras["exposure"] = fit.exposure
    if fit.vignetting is not None:
        extras["vignetting"] = fit.vignetting
    if fit.illumination is not None:
        extras["illumination"] = fit.illumination
    if passes.alignment is not None:
        extras["alignment"] = passes.alignment
        problem = dataclasses.replace(problem, cameras=passes.cameras)   # relit through the corrected cameras
    timings = {"render": passes.render_s, "solve": passes.solve_s}
    if options.relight.enabled:
        t = time.perf_counter()
        extras["relit_images"] = relight_outputs(problem, params, fit.estimate, options.relight)
        timings["relight"] = time.perf_counter() - t
    timings["method"] = time.perf_counter() - started
    return MethodResult(
        estimate=fit.estimate, renders=passes.renders, parameters=params, reconstructions=fit.images(),
        reconstruction_variance=fit.image_variances(),
        pixel_weights=fit.pixel_weights, pixel_reasons=fit.pixel_reasons, timings_s=timings, std=std, observable=fit.observable,
        cost_history=list(sol.cost_history) if sol else [],
        cost_times_s=[at - started for at, _ in sol.iterates] if sol else [], trace=trace.entries(),
        extras=extras)
