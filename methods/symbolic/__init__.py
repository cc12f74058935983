"""``method=symbolic``: symbolic ray tracing (Coubard et al., sections 4.2-4.4).

One polynomial rendering pass gives every pixel as a polynomial in the kernel weights (eq. 7-8);
the L2 cost (eq. 6, p = 2) becomes μᵀGμ - 2bᵀμ + yᵀy in the monomials μ, minimised exactly with
nlopt, with no more rendering.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from framework.cache import Cache
from framework.config import method_defaults
from framework.errors import ConfigError
from framework.executor import make_executor
from framework.memory import release_freed_memory
from framework.registry import Method, MethodResult, register
from framework.relight import relight_outputs
from methods._common import Trace, check_choice, check_number, initial_guess, segment_groups
from methods.symbolic.basis import MonomialBasis
from methods.symbolic.field import ROBUST_LOSSES, FieldOptions, fit_field
from methods.symbolic.per_segment import fit_per_segment
from methods.symbolic.polynomial_pass import polynomial_pass
from methods.symbolic.solve import check_solve_memory, solve_polynomial
from methods.symbolic.uncertainty import (
    correlation_extra,
    ill_determined,
    observable_parameters,
    parameter_uncertainty,
    restrict_system,
    score_meat,
)


@register("symbolic")
class SymbolicMethod(Method):
    """Symbolic-ray-tracing inversion of the kernel weights ρ.

    Configuration (``framework/conf/method/symbolic.yaml``)
    -------------------------------------------------------
    kernels : ``all`` or list of kernel names, default ``all``
        The kernels to estimate; others are treated as absent (``[diffuse]`` is the paper's
        Lambertian setting, Table 1).
    init : ``guess`` | ``lambertian_prior``, default ``guess``
        Initial guess (drives the kernel selection of the polynomial pass and starts the solve).
    guess : float or mapping kernel -> float, default 0.5
    prob_floor : float in [0, 1], default 0.1
        Every kernel of a segment keeps at least this selection probability, so the polynomial
        is unbiased for every ρ, not only near the guess.
    gram : ``cross`` | ``plain``, default ``cross``
        ``cross`` splits the samples into two independent halves and builds G = ½(AᵀB + BᵀA):
        unbiased, whereas ``plain`` G = AᵀA adds the coefficients' Monte Carlo covariance to G,
        which shrinks the estimates at low spp (regression dilution).
    psd : bool, default true
        Project each channel's G onto the positive semi-definite matrices before the solve
        (:meth:`GramSystem.psd`): the cross Gram is unbiased but not PSD, and along directions
        the pixels barely constrain its negative eigenvalues pull the solve to the constraints.
    tail_bounces : int in [0, 16], default 4
        T, reflections traced beyond N_max and weighted by the guesses (the light the paper's
        truncation drops; :class:`PolynomialPathIntegrator`); taken when ``render.tail_bounces``
        is ``auto`` (its default). ``method=symbolic_paper`` sets 0.
    refine : int in [0, 8], default 3
        Cap on further polynomial passes, each rendered with the previous estimate as guesses
        and solved from it (one render each). With a tail this moves its linearisation point to
        the estimate, so the light beyond N_max is weighted by nearly the right ρ; it also makes
        the kernel selection match the estimate. ``method=symbolic_paper`` sets 0.
    refine_tol : float >= 0, default 0.005
        Refinement stops once no weight moved more than ``refine_tol + 2 std`` between two
        passes (each pass has its own samples, so the estimate cannot settle closer than its
        Monte Carlo noise). ``extras["refine_moves"]`` holds each pass's largest move in those
        units and ``extras["refine_stopped"]`` why the passes stopped.
    exposure : ``scene`` | ``known``, default ``scene``
        ``scene``: as scene.yaml's ``photometry`` says; with ``exposure: per_view`` one gain per
        view and channel is solved jointly with ρ (:mod:`methods.symbolic.field`), reported in
        results.json ``exposure``. ``known``: every gain 1.
    weights : ``scene`` | ``none``, default ``scene``
        ``scene``: the scene's pixel weights (masks, saturated and black-clipped pixels, pixels
        outside the delivered image are left out). ``none``: every pixel counts.
    robust : ``auto`` | ``none`` | ``cauchy`` | ``huber``, default ``auto``
        Robust reweighting (IRLS from the stored coefficients, no render) against objects the
        model lacks (cars, people). ``auto``: Cauchy for photographs (images decoded from 8/16-bit
        files, pixel weights or per-view exposure: unmodelled objects are certain there), none for
        linear radiance (synthetic renders of the model, where every pixel is the model's and
        the L2 fit is the efficient one). The final weights are the run's
        ``images/<view>.weights.exr``.
    boundary : ``auto`` or int in [0, 8], default ``auto``
        Pixels within this many pixels of a change of segment are left out: a photograph
        resampled from a distorted camera interpolates across the edge, mixing two materials
        that the pass's box-filtered pixel keeps apart. ``auto``: 1 when some view was resampled
        (a distorted camera), else 0.
    irls.iterations : int in [1, 100], default 10; irls.tol : float >= 0, default 1e-3
        Cap on the robust rounds, and the largest move of a weight or gain below which they stop.
    memory_mb : float > 0, default 512
        Memory for the coefficient tiles of the pass; sets the tile size.
    cost : ``joint`` | ``per_segment``, default ``joint`` (``lambertian_prior``: ``per_segment``)
        ``joint``: one L2 cost over every pixel (eq. 6). ``per_segment``: each segment's weights
        fitted to the pixels that see it, the others at their estimates, all together (the
        estimating equations of :mod:`methods.symbolic.per_segment`): a segment the kernels
        cannot reproduce keeps its misfit in its own weights instead of moving those of the
        segments it lights; a segment no pixel sees is held at its guess. ``extras["cost"]``,
        ``extras["per_segment"]``.
    std : ``sandwich`` | ``residual``, default ``sandwich``
        Standard errors (:mod:`methods.symbolic.uncertainty`). ``sandwich``: ``H⁺MH⁺`` with
        ``M`` the covariance of the cost's gradient from each pixel's own term (image noise and
        the coefficients' Monte Carlo noise, the latter from the pass's two half-sample
        estimates, kept for it beside Γ); measured RMS z = (estimate - reference)/std 0.95 and
        |z| < 2 for 96 % (tests/test_std_calibration.py). ``residual``: ``2σ²H⁺`` from the
        image residual only (the formula before the sandwich): it misses the Monte Carlo noise
        of the coefficients, RMS z 18 there, and is 0 where the cross Gram's cost at the
        estimate is <= 0. Neither covers the bias of observations holding more than N_max
        reflections (``observe.max_depth`` above N_max + 1) nor that of ``gram: plain``, whose
        sandwich also lacks the halves (first-order noise only).
    solver.algorithm : ``SQP`` | ``LD_SLSQP`` | ``LD_MMA`` | ``LD_CCSAQ``, default ``SQP``
        ``SQP``: sequential quadratic programming on the exact Hessian of the polynomial cost
        (:func:`framework.optim.minimize_sqp`; each step an exact QP under the bounds and the
        Σρ <= 1 constraints); the others are nlopt's. On urban_canyon and cornell_box (all
        views) SQP and ``LD_SLSQP`` end within 5e-8 of each other; SQP needs fewer
        evaluations, and its QP stays cheap where SLSQP's dense subproblem over hundreds of
        parameters dominates the solve (BENCHMARKS.md, section 5).
    solver.starts : int >= 1 or ``auto``, default ``auto``
        Starts per channel and parameter block: the initial guess, then seeded random feasible
        points; ``auto``: 4 for blocks of at most 32 parameters, 1 above
        (:data:`~methods.symbolic.solve.AUTO_STARTS_MAX_PARAMS` says what was measured).
    solver.max_eval : int >= 1, default 2000
        Evaluations per start (SQP: iterations per start).
    solver.xtol_rel, solver.ftol_rel : float >= 0, default 1e-8, 1e-12
        nlopt's relative tolerances on the (preconditioned) weights and on the cost; SQP stops
        when no weight steps more than ``xtol_rel`` or the cost drops by at most ``ftol_rel``
        of itself.
    solver.precondition : bool, default true
        nlopt only: solve in coordinates where the cost's Hessian is about the identity
        (:func:`~methods.symbolic.solve.solve_polynomial`): 3-5 times fewer evaluations.

    relight : mapping, optional
        ``{enabled: false, sun_direction: [x, y, z] | null, sun_irradiance: null, sky_radiance: null,
        spp: 64, reflectance: diffuse}``: when enabled, ``extras["relit_images"]`` holds
        ``<view>.relit`` (path-traced at the estimate under the new light) and
        ``<view>.reflectance`` (shadow-free albedo) (H, W, C) arrays (:mod:`framework.relight`);
        not counted in ``renders`` (post-inversion), timed as ``timings_s["relight"]``.

    Uses ``render.spp``, ``render.max_bounces`` (N_max), ``render.tail_bounces`` (T: light beyond
    N_max reflections, linearised at the guesses, see :class:`PolynomialPathIntegrator`; 0 is the
    paper's truncation), ``seed`` and ``executor`` (views rendered
    in Dask workers, :mod:`framework.executor`) of the main config.

    Uncertainty (:mod:`methods.symbolic.uncertainty`): parameters no pixel depends on are
    ``observable`` False (estimate and std NaN) and left out of the solve; ``std`` per the
    ``std`` option (``extras["std_method"]``: the formula used); ``extras["correlation"]`` holds
    the labels ``segment/kernel`` of the observable parameters and their channel-mean correlation
    matrix; ``extras["ill_determined"]`` is a list of P bools, in ``parameters`` order: True for
    an observable parameter whose std exceeds 0.05 in some channel or is NaN
    (:func:`~methods.symbolic.uncertainty.ill_determined`).
    ``extras["n_monomials"]``: the monomials that occur (at most C(D + N_max, N_max));
    ``extras["gram_nnz"]``: stored entries of the sparse G, all channels.
    Limitations: kernel BRDFs only (paper section 4.3). The solve costs O(nnz(G)) per evaluation
    and O(D²) memory per Hessian. The PSD projection is exact on each connected component of G
    of at most :data:`~methods.symbolic.gram.PSD_BLOCK_LIMIT` monomials; larger components are
    left unprojected (a log warning, and their sizes in ``extras["psd_skipped_components"]``).
    """

    kernels: tuple[str, ...] | None = None     # fixed by subclasses (lambertian_prior)

    def parameters(self, problem):
        kernels = self.kernels
        if kernels is None and self.cfg.get("kernels", "all") != "all":
            kernels = tuple(self.cfg.kernels)
        return problem.scene.parameters(kernels=kernels)

    def check(self):
        check_number(self.cfg, "prob_floor", 0.0, 1.0)
        check_choice(self.cfg, "gram", ("cross", "plain"))
        check_choice(self.cfg, "psd", ("True", "False"))
        check_number(self.cfg, "memory_mb", 0.0, lo_open=True)
        solver, section = self.cfg.solver, "method.solver"
        if str(solver.starts) != "auto":
            check_number(solver, "starts", 1, integer=True, section=section)
        check_number(solver, "max_eval", 1, integer=True, section=section)
        check_number(solver, "xtol_rel", 0.0, section=section)
        check_number(solver, "ftol_rel", 0.0, section=section)
        check_choice(solver, "precondition", ("True", "False"), section=section)
        if "refine" in self.cfg:
            check_number(self.cfg, "refine", 0, 8, integer=True)
        if "refine_tol" in self.cfg:
            check_number(self.cfg, "refine_tol", 0.0)
        if "tail_bounces" in self.cfg:
            check_number(self.cfg, "tail_bounces", 0, 16, integer=True)
        if "std" in self.cfg:
            check_choice(self.cfg, "std", ("sandwich", "residual"))
        if "cost" in self.cfg:
            check_choice(self.cfg, "cost", ("joint", "per_segment"))
            if self.cfg.cost == "per_segment" and self.cfg.get("std", "sandwich") == "residual":
                raise ConfigError("method.std=residual is the joint cost's formula: with method.cost=per_segment "
                                  "use method.std=sandwich, or method.cost=joint")
        check_choice(solver, "algorithm", ("SQP", "LD_SLSQP", "LD_MMA", "LD_CCSAQ"), section=section)
        for key, choices in (("exposure", ("scene", "known")), ("weights", ("scene", "none")),
                             ("robust", ("auto",) + ROBUST_LOSSES)):
            if key in self.cfg:
                check_choice(self.cfg, key, choices)
        if "boundary" in self.cfg and str(self.cfg.boundary) != "auto":
            check_number(self.cfg, "boundary", 0, 8, integer=True)
        if "irls" in self.cfg:
            check_number(self.cfg.irls, "iterations", 1, 100, integer=True, section="method.irls")
            check_number(self.cfg.irls, "tol", 0.0, section="method.irls")

    def check_problem(self, problem) -> None:
        self.check()
        FieldOptions.from_config(self.cfg, problem, boundaries=False)   # a reference view outside the views

    def run(self, problem) -> MethodResult:
        self.check()
        t0 = time.perf_counter()
        params = self.parameters(problem)
        sub = dataclasses.replace(problem, parameters=params)
        x0, renders = initial_guess(self.cfg, sub, prior=_lambertian_prior)
        guess0 = x0
        trace = Trace(t0)
        trace.record(renders, x0)
        settings = problem.settings
        render_s = solve_s = 0.0
        stages = {}
        field = FieldOptions.from_config(self.cfg, problem)
        refine, tol = int(self.cfg.get("refine", 0)), float(self.cfg.get("refine_tol", 0.0))
        moves, stopped = [], "single pass" if refine == 0 else f"cap of {refine} refinement pass(es)"
        fit: dict = {}
        for k in range(1 + refine):
            if k:      # re-render at the estimate: better kernel selection, and a tail at the estimate
                x0 = np.where(np.isnan(fit["estimate"]), x0, fit["estimate"])
            result = self._pass(sub, params, x0, seed=int(problem.seed) + 7777 * renders)
            renders += 1
            t_solve = time.perf_counter()
            previous = fit
            fit = self._fit(result, params, x0, problem, field, start=previous.get("robust_weights"))
            _record_iterates(trace, renders, fit)
            render_s += result.render_s
            solve_s += time.perf_counter() - t_solve     # PSD projection, nlopt and uncertainty
            stages = {name: stages.get(name, 0.0) + t for name, t in fit["stages_s"].items()}
            if k:
                fit = _carried(previous, fit)
                moves.append(_moved(previous["estimate"], fit["estimate"], fit["std"], tol))
                if moves[-1] <= 1.0:
                    stopped = (f"converged after {k} refinement pass(es): no weight moved more than "
                               f"refine_tol + 2 std ({moves[-1]:.2f} of it)")
                    break
        estimate = fit["estimate"]
        sol = fit["solve"]
        extras = {"n_monomials": fit["n_monomials"], "gram_nnz": fit["gram_nnz"],
                  "parameter_blocks": len(sol.blocks) if sol else 0, "psd_skipped_components": list(fit["psd_skipped"]), "solver_evaluations": sol.n_evals if sol else 0,
                  "solver_evaluations_from_guess": sol.guess_evals if sol else 0,
                  "initial_guess": guess0.tolist(), "views_from_cache": result.from_cache,
                  "correlation": fit["correlation"], "residual_variance": fit["sigma2"],
                  "std_method": fit["std_method"],
                  "ill_determined": ill_determined(fit["std"], fit["observable"]).tolist(),
                  "executor": str(settings.executor.get("name", "serial")),
                  "solve_stages_s": stages, "refine_moves": moves, "refine_stopped": stopped}
        extras["cost"] = str(self.cfg.get("cost", "joint"))
        if "per_segment" in fit:
            extras["per_segment"] = fit["per_segment"]
        if field.active:
            extras["field"] = field.describe(fit)
        if fit.get("exposure") is not None:
            extras["exposure"] = fit["exposure"]
        timings = {"render": render_s, "solve": solve_s}
        relit = self._relight(sub, params, estimate)
        if relit is not None:
            extras["relit_images"], timings["relight"] = relit
        timings["method"] = time.perf_counter() - t0
        return MethodResult(
            estimate=estimate, renders=renders, parameters=params, reconstructions=fit["images"](),
            pixel_weights=fit.get("pixel_weights"),
            timings_s=timings, std=fit["std"], observable=fit["observable"],
            cost_history=list(sol.cost_history) if sol else [],
            cost_times_s=[at - t0 for at, _ in sol.iterates] if sol else [], trace=trace.entries(),
            extras=extras)

    def render_at(self, problem, rho: np.ndarray, *, seed: int = 0) -> dict[str, np.ndarray]:
        """One polynomial pass at the initial guess, evaluated at ρ (restricted to this method's
        kernels): the images the solve compares with the observations."""
        params = self.parameters(problem)
        index = {(p.segment, p.kernel): p.index for p in problem.parameters}
        sub = dataclasses.replace(problem, parameters=params)
        x0, _ = initial_guess(self.cfg, sub, prior=_lambertian_prior)
        result = self._pass(sub, params, x0, seed=seed)
        basis = MonomialBasis(len(params), problem.settings.max_bounces, result.codes)
        return _images(result, basis, rho[[index[(p.segment, p.kernel)] for p in params]], problem.cameras)

    def _pass(self, problem, params, x0, *, seed: int):
        """The polynomial pass of every view with guesses ``x0`` (one render)."""
        settings = problem.settings
        with make_executor(settings.executor) as executor:
            return polynomial_pass(problem, params, x0, settings.max_bounces, spp=settings.spp,
                                   tail_bounces=settings.tail_bounces, seed=seed,
                                   prob_floor=float(self.cfg.prob_floor), memory_mb=float(self.cfg.memory_mb),
                                   cache=Cache(settings.cache_dir), executor=executor,
                                   cross_gram=self.cfg.get("gram", "cross") == "cross")

    def _fit(self, result, params, x0, problem, field, start=None) -> dict:
        """The solve of one pass: on the pass's own system, or through the field path
        (:func:`~methods.symbolic.field.fit_field`: pixel weights, gains, robust IRLS).

        Returns :meth:`_solve`'s dict plus ``n_monomials``, ``gram_nnz``, ``images`` (a
        function giving the reconstructions) and, from the field path, ``exposure`` and
        ``pixel_weights``; ``start``: the robust weights the previous pass ended with.
        """
        if field.active:
            result.take_system()    # released: the field fit forms its own weighted systems
            return fit_field(result, params, x0, problem, field, self._solve, start=start)
        basis = MonomialBasis(len(params), problem.settings.max_bounces, result.codes)
        views = lambda: ((result.coefficients(cam.name), problem.observed[cam.name], None) for cam in problem.cameras)
        nnz = result.system.nnz
        # handed over, not held here: the solve releases it once restricted
        fit = self._solve(result.take_system(), basis, params, x0, problem, views=views)
        # unobservable: monomials 0; held by the per-segment fit: its guess
        estimate = fit.get("at", np.nan_to_num(fit["estimate"]))
        fit.update(n_monomials=basis.size, gram_nnz=nnz,
                   images=lambda: _images(result, basis, estimate, problem.cameras))
        return fit

    def _solve(self, system, basis, params, x0, problem, *, views=None, groups=None) -> dict:
        """Solve on the observable parameters; NaN estimate and std for the others.

        ``views``: a function giving ``(coefficients, y, weights or None)`` per view, the
        per-pixel terms the ``sandwich`` std needs (None: the ``residual`` std). ``groups``:
        the parameter indices sharing a Σρ <= 1 constraint (default: per segment).

        Returns a dict: ``estimate`` (P, C), ``std`` (P, C), ``observable`` (P,), ``solve``
        (SolveResult or None when nothing is observable), ``iterates`` (the solve's
        ``(clock, (P, C) estimate)``, NaN where unobservable), ``correlation`` (the JSON-able
        ``extras["correlation"]``), ``sigma2`` (residual variance per channel, a list),
        ``std_method`` (``sandwich`` or ``residual``), ``stages_s`` (seconds of the PSD
        projection, the nlopt runs and the uncertainty) and ``psd_skipped``.
        """
        method = str(self.cfg.get("std", "sandwich")) if views is not None else "residual"
        P, C = len(params), problem.n_channels
        groups = segment_groups(params) if groups is None else groups
        if self.cfg.get("cost", "joint") == "per_segment":
            return fit_per_segment(system, basis, params, x0, problem, views=views, groups=groups,
                                   xtol=float(self.cfg.solver.xtol_rel), psd=bool(self.cfg.get("psd", True)))
        observable = observable_parameters(system, basis)
        estimate, std = np.full((P, C), np.nan), np.full((P, C), np.nan)
        if not observable.any():
            return {"estimate": estimate, "std": std, "observable": observable, "solve": None, "iterates": [],
                    "correlation": correlation_extra(params, observable, None), "sigma2": None,
                    "std_method": method, "stages_s": {}, "psd_skipped": ()}
        check_solve_memory(system, basis)
        sub_system, sub_basis, columns = restrict_system(system, basis, observable)
        del system                     # the caller hands it over (PassResult.take_system)
        t_psd = time.perf_counter()
        if self.cfg.get("psd", True):
            sub_system = sub_system.psd()
        t_psd = time.perf_counter() - t_psd
        kept = np.flatnonzero(observable)
        position = {int(j): k for k, j in enumerate(kept)}
        groups = [[position[j] for j in g if j in position] for g in groups]
        solver = self.cfg.solver
        sol = solve_polynomial(sub_system, sub_basis, segments_params=[g for g in groups if g],
                               x0=x0[kept], algorithm=str(solver.algorithm), starts=solver.starts if str(solver.starts) == "auto" else int(solver.starts),
                               max_eval=int(solver.max_eval), xtol_rel=float(solver.xtol_rel),
                               ftol_rel=float(solver.ftol_rel), precondition=bool(solver.precondition),
                               seed=int(problem.seed), executor=_block_executor(problem.settings.executor))
        t_unc = time.perf_counter()
        release_freed_memory()       # the restriction's and the solve's temporaries
        meat = None
        if method == "sandwich":
            meat = score_meat(sub_basis, sol.estimate, views(), columns, basis.codes)
        unc = parameter_uncertainty(sub_system, sub_basis, sol.estimate, meat=meat)
        estimate[kept], std[kept] = sol.estimate, unc.std
        stages = {"psd": t_psd, "nlopt": sol.solve_s, "uncertainty": time.perf_counter() - t_unc}
        return {"estimate": estimate, "std": std, "observable": observable, "solve": sol,
                "iterates": [(at, _full(observable, x)) for at, x in sol.iterates],
                "correlation": correlation_extra(params, observable, unc),
                "sigma2": [float(v) for v in unc.sigma2], "std_method": method, "stages_s": stages,
                "psd_skipped": sub_system.psd_skipped}

    def _relight(self, problem, params, estimate):
        """``(images, seconds)`` of the ``relight`` option, or None when it is off (see
        :func:`framework.relight.relight_outputs`)."""
        opt = self.cfg.get("relight")
        if not opt or not opt.get("enabled", False):
            return None
        t = time.perf_counter()
        images = relight_outputs(problem, params, estimate, opt)
        return images, time.perf_counter() - t


def _block_executor(cfg):
    """``executor=dask``: a function starting the executor the solve puts independent parameter
    blocks on (only when there are several); serial: None (the blocks in turn, in process)."""
    if cfg is None or str(cfg.get("name", "serial")) == "serial":
        return None
    return lambda: make_executor(cfg)


def _lambertian_prior(problem) -> MethodResult:
    """``method.init=lambertian_prior``: the symbolic inversion of the diffuse weights with the
    ``lambertian_prior`` method's shipped options but one pass (a start needs no refinement;
    that method is this class with diffuse kernels) and the joint cost (:func:`prior_config`)."""
    return SymbolicMethod(prior_config()).run(problem)


def prior_config():
    """The ``lambertian_prior`` method's shipped options with ``refine: 0`` and ``cost: joint``:
    the one-pass prior that ``method.init=lambertian_prior`` starts from
    (:func:`methods._common.initial_guess`). Joint, because the fits it starts minimise the joint
    cost: measured on the small street, all views, seeds 0-3 (tests/test_inversion.py), the
    kernel solve from the joint prior took 30, 30, 25, 45 evaluations, from the per-segment
    prior 62, 33, 27, 34 (flat guess: 31, 29, 28, 59), with the same errors (mean 0.0166 and
    0.0167)."""
    from omegaconf import open_dict
    cfg = method_defaults("lambertian_prior")
    with open_dict(cfg):
        cfg.refine = 0
        cfg.cost = "joint"
    return cfg


def _images(result, basis: MonomialBasis, rho: np.ndarray, cameras) -> dict[str, np.ndarray]:
    """Every view's polynomial evaluated at ρ (P, C): (H, W, C) images."""
    mu = np.stack([basis.evaluate(rho[:, c]) for c in range(rho.shape[1])])
    return {cam.name: result.image(cam.name, mu, (cam.height, cam.width)) for cam in cameras}


def _carried(previous: dict, fit: dict) -> dict:
    """``fit`` with the estimate and std of the parameters it could not observe but the previous
    pass could taken from that pass: a weight seen through a handful of paths may get none in
    the next pass's samples, which says nothing new about it."""
    lost = previous["observable"] & ~fit["observable"]
    if not lost.any():
        return fit
    out = dict(fit)
    out["estimate"], out["std"] = fit["estimate"].copy(), fit["std"].copy()
    out["estimate"][lost], out["std"][lost] = previous["estimate"][lost], previous["std"][lost]
    out["observable"] = fit["observable"] | lost
    return out


def _moved(previous: np.ndarray, current: np.ndarray, std: np.ndarray, tol: float) -> float:
    """Largest change of an estimate between two passes in units of ``tol + 2 std``: below 1 the
    passes agree within their Monte Carlo noise (each pass has its own samples, so the estimate
    never settles closer than that) or within ``tol``. Parameters estimated in both passes with a
    finite std count: one without (the data do not pin it; reported ill-determined) wanders from
    pass to pass whatever the passes do (measured on a 70-material street: an awning seen by a
    few pixels went 0, 0.50, 0.68, 0 and held the refinement to its cap)."""
    both = np.isfinite(previous) & np.isfinite(current) & np.isfinite(std)
    if not both.any():
        return 0.0
    scale = tol + 2.0 * np.where(both, std, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.abs(current - previous) / scale
    return float(np.nanmax(np.where(both, ratio, 0.0)))


def _full(observable: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``(P, C)`` from the observable parameters' ``x``, NaN elsewhere."""
    full = np.full((len(observable), x.shape[1]), np.nan)
    full[observable] = x
    return full


def _record_iterates(trace: Trace, renders: int, fit: dict) -> None:
    """The solve's iterates as full (P, C) estimates, NaN where unobservable."""
    for at, x in fit["iterates"]:
        trace.record(renders, x, at=at)
