"""The passes of ``method=symbolic``: a polynomial pass, its fit, and further passes at the estimate.

Each pass renders every view once at guesses ``x0``
(:func:`~methods.symbolic.system.polynomial_pass.polynomial_pass`)
and is solved without more rendering: through the joint cost, the per-segment estimating
equations, or the field path around either (pixel weights, exposure gains, robust rounds). With
``refine`` > 0 the next pass is rendered at the estimate (the tail's linearisation and the kernel
selection move there) until no weight moved beyond ``refine_tol`` plus what the Monte Carlo
noise of two passes explains for that many weights (:func:`moved`), or the cap. With ``align`` each view's camera is registered to the prediction before the
next pass (:mod:`methods.symbolic.misfit.alignment`). With ``bias=richardson`` the last pass is also
fitted at half its spp and the estimate extrapolated (:mod:`methods.symbolic.loop.richardson`).
"""
from __future__ import annotations

import contextlib
import dataclasses
import time

import numpy as np

from framework.cache import Cache
from framework.executor import make_executor
from framework.memory import reused_memory
from methods._common import Trace, segment_groups
from methods.symbolic.fit.field import FieldOptions, fit_field
from methods.symbolic.fit.fit import Fit, StageClock, fields_at, with_quality
from methods.symbolic.fit.joint import fit_joint
from methods.symbolic.fit.per_segment import fit_per_segment
from methods.symbolic.fit.with_known import fit_with_known
from methods.symbolic.loop.resolved import resolve
from methods.symbolic.loop.richardson import extrapolated
from methods.symbolic.misfit.alignment import Alignment
from methods.symbolic.options import SymbolicOptions
from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.polynomial_pass import polynomial_pass


@dataclasses.dataclass
class Passes:
    """What the passes of one run gave: the last fit and the bookkeeping of the run's results."""

    fit: Fit
    renders: int
    render_s: float
    solve_s: float
    stages_s: dict
    moves: list
    stopped: str
    from_cache: list
    field: FieldOptions
    resolved: dict                 # results.json options_resolved: each auto option's value and why
    cameras: list                  # those of the last pass: corrected with method.align
    alignment: list | None         # results.json alignment (method.align), else None


def run_passes(problem, params, x0: np.ndarray, options: SymbolicOptions, *, renders: int, trace: Trace) -> Passes:
    """Render and fit passes until the estimate stops moving (module docstring).

    ``problem`` holds ``params`` as its parameters; ``renders``: passes already spent (a prior);
    every solver evaluation is recorded in ``trace``. A run on the field path keeps the memory its
    arrays free for the next ones from its first pass to its last fit
    (:func:`~framework.memory.reused_memory`): its fits make the same large dense systems again
    and again, and a fresh page costs the kernel a fault and a zeroing (bundled
    urban_canyon_survey, passes from the cache, alternated, 2026-12-06: solve 60.2 and 64.0 s
    with the memory returned after each fit, 52.9 and 56.8 s kept; system CPU time 16-19 s
    against 6-7 s). The joint fit's runs return theirs after each restriction instead
    (:func:`~framework.memory.release_freed_memory`): the street's peak memory is their target.
    """
    decided = resolve(options, problem)
    field = FieldOptions.resolve(decided.options, problem)
    with reused_memory() if field.active else contextlib.nullcontext():
        return _passes(problem, params, x0, decided, field, renders=renders, trace=trace)


def _passes(problem, params, x0: np.ndarray, decided, field: FieldOptions, *, renders: int, trace: Trace) -> Passes:
    """:func:`run_passes` with its options ``decided`` and ``field`` resolved."""
    options = decided.options
    stopped = "single pass" if options.refine == 0 else f"cap of {options.refine} refinement pass(es)"
    render_s = solve_s = 0.0
    moves, fit = [], None
    clock = StageClock()
    # method.align: between passes each view's camera is registered to the prediction at the
    # estimate; the next pass renders (and caches, its key holds the pose) the corrected cameras
    alignment = Alignment(problem.cameras, mode=options.align, max_px=options.align_max_px,
                          min_px=options.align_min_px) \
        if options.align != "none" else None
    for k in range(1 + options.refine):
        if k:      # re-render at the estimate: better kernel selection, and a tail at the estimate
            x0 = np.where(np.isnan(fit.estimate), x0, fit.estimate)
            if alignment is not None:
                t_align = time.perf_counter()
                with clock("registration"):
                    problem = alignment.update(problem, fit, before_pass=k)
                    field = FieldOptions.resolve(options, problem)    # the boundary pixels follow the cameras
                solve_s += time.perf_counter() - t_align
        result = render_pass(problem, params, x0, options, seed=int(problem.seed) + 7777 * renders)
        renders += 1
        t_solve = time.perf_counter()
        previous = fit
        start = previous.robust_weights if previous is not None else None
        fit = fit_pass(result, params, x0, problem, options, field, start=start)
        for at, x in fit.iterates:
            trace.record(renders, x, at=at)
        render_s += result.render_s
        clock.add(fit.stages_s)
        if k:
            fit = carried(previous, fit)
            moves.append(moved(previous.estimate, fit.estimate, fit.std, options.refine_tol))
        solve_s += time.perf_counter() - t_solve     # the fit (its stages) and the comparison of passes
        if k and moves[-1] <= 1.0 and (alignment is None or not alignment.moved()):   # and no camera moved
            stopped = (f"converged after {k} refinement pass(es): no weight moved beyond refine_tol + "
                       f"the two passes' noise ({moves[-1]:.2f} of it)")
            break
    t_solve = time.perf_counter()
    with clock("fit_quality"):         # the last pass's only: the run reports no other
        fit = with_quality(fit)
    solve_s += time.perf_counter() - t_solve
    if options.bias == "richardson":    # the last pass refitted at half its spp, from its own render
        t_solve = time.perf_counter()
        # the field fit forms its own weighted systems: the half passes' summed ones are not built
        with clock("bias_refits"):
            fit = extrapolated(fit, lambda j: fit_pass(result.halved(j, problem.observed, system=not field.active),
                                                       params, x0, problem, options, field, start=start,
                                                       estimate_only=True),
                               segments=segment_groups(params))
        solve_s += time.perf_counter() - t_solve
    stages = clock.seconds
    stages["other"] = max(0.0, solve_s - sum(stages.values()))    # what no stage names
    return Passes(fit, renders, render_s, solve_s, stages, moves, stopped, result.from_cache, field, decided.why,
                  problem.cameras, alignment.report(problem.cameras) if alignment is not None else None)


def render_pass(problem, params, x0: np.ndarray, options: SymbolicOptions, *, seed: int):
    """The polynomial pass of every view with guesses ``x0`` (one render)."""
    settings = problem.settings
    with make_executor(settings.executor) as executor:
        return polynomial_pass(problem, params, x0, settings.max_bounces, spp=settings.spp,
                               tail_bounces=settings.tail_bounces, seed=seed, prob_floor=options.prob_floor,
                               memory_mb=options.memory_mb, cache=Cache(settings.cache_dir), executor=executor,
                               cross_gram=options.gram == "cross", footprint=options.footprint == "resampled",
                               quarters=options.bias == "richardson")


def fit_pass(result, params, x0: np.ndarray, problem, options: SymbolicOptions, field: FieldOptions, *,
             start: dict | None = None, estimate_only: bool = False) -> Fit:
    """The fit of one pass: on the pass's own system, or through the field path
    (:func:`~methods.symbolic.fit.field.fit_field`); ``start``: the robust weights the previous pass
    ended with; ``estimate_only``: no standard errors nor fit quality (the bias correction's half
    refits use the estimate alone)."""
    solve = lambda system, basis, every, x, pb, *, views, groups, defer_std=False: solve_system(  # noqa: E731
        system, basis, every, x, pb, options, views=views, groups=groups, defer_std=defer_std)
    if field.active:
        result.system = None    # released: the field fit forms its own weighted systems
        return fit_field(result, params, x0, problem, field, solve, start=start, estimate_only=estimate_only)
    basis = MonomialBasis(len(params), problem.settings.max_bounces, result.codes)
    views = lambda: ((result.coefficients(cam.name), problem.observed[cam.name], None)  # noqa: E731
                     for cam in problem.cameras)
    nnz = result.system.nnz
    # handed over, not held here: the solve releases it once restricted
    fit = solve(result.take_system(), basis, params, x0, problem, views=views, groups=segment_groups(params),
                defer_std=estimate_only)
    return fit.replace(n_monomials=basis.size, gram_nnz=nnz,
                       **fields_at(result, basis, fit.evaluated_at, problem.cameras))


def solve_system(system, basis, params, x0: np.ndarray, problem, options: SymbolicOptions, *, views,
                 groups, defer_std: bool = False) -> Fit:
    """The fit of a summed system by the cost ``options.cost`` names, the known weights of the
    scene substituted (:func:`~methods.symbolic.fit.with_known.fit_with_known`); ``defer_std``: the joint
    cost's standard errors left to :func:`~methods.symbolic.fit.fit.with_std` (the per-segment fit
    computes them with its blocks)."""
    def solve(system, basis, params, x0, problem, *, views, groups, defer_std):
        if options.cost == "per_segment":
            return fit_per_segment(system, basis, params, x0, problem, views=views, groups=groups,
                                   xtol=options.solver.xtol_rel, psd=options.psd,
                                   std_device=options.std_device == "device")
        return fit_joint(system, basis, params, x0, problem, options, views=views, groups=groups,
                         defer_std=defer_std)
    return fit_with_known(solve, system, basis, params, x0, problem, views=views, groups=groups,
                          defer_std=defer_std)


def carried(previous: Fit, fit: Fit) -> Fit:
    """``fit`` with the estimate and std of the parameters it could not observe but the previous
    pass could taken from that pass: a weight seen through a handful of paths may get none in
    the next pass's samples, which says nothing new about it."""
    lost = previous.observable & ~fit.observable
    if not lost.any():
        return fit
    estimate, std = fit.estimate.copy(), fit.std.copy()
    estimate[lost], std[lost] = previous.estimate[lost], previous.std[lost]
    return fit.replace(estimate=estimate, std=std, observable=fit.observable | lost)


#: family-wise level of the refinement's stop test: the chance that passes which agree up to their
#: Monte Carlo noise are taken for passes that still move (and another pass is rendered)
STOP_LEVEL = 0.05


def noise_bound(n: int) -> float:
    """``z`` such that ``n`` independent standard normal values all lie within ``±z`` with
    probability ``1 - STOP_LEVEL`` (Šidák): 1.96 for one, 2.86 for 12, 3.82 for 384."""
    from scipy.stats import norm
    return float(norm.ppf(0.5 + 0.5 * (1.0 - STOP_LEVEL) ** (1.0 / max(int(n), 1))))


def moved(previous: np.ndarray, current: np.ndarray, std: np.ndarray, tol: float) -> float:
    """Largest change of an estimate between two passes in units of ``tol + z_n √2 std``.

    Each pass has its own samples, so two passes' estimates differ by Monte Carlo noise of standard
    deviation at most ``√2 std`` (``std`` also holds the image noise, which both passes share).
    Compared one by one against a fixed multiple of that, one weight of many always moves beyond
    it: against ``2 std`` each weight does so with probability 0.16, and a street of 128
    weights x 3 channels would never stop before the cap. ``z_n`` (:func:`noise_bound`) is the bound
    that ``n`` such differences all keep with probability 0.95, so below 1 the passes agree within
    their noise (or within ``tol``) for the run as a whole. Parameters estimated in both passes
    with a finite std count (``n`` of them): one without (the data do not pin it; reported
    ill-determined) wanders from pass to pass whatever the passes do."""
    both = np.isfinite(previous) & np.isfinite(current) & np.isfinite(std)
    if not both.any():
        return 0.0
    scale = tol + np.sqrt(2.0) * noise_bound(int(both.sum())) * np.where(both, std, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.abs(current - previous) / scale
    return float(np.nanmax(np.where(both, ratio, 0.0)))
