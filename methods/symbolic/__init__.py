"""``method=symbolic``: symbolic ray tracing (Coubard et al., sections 4.2-4.4).

One polynomial rendering pass gives every pixel as a polynomial in the kernel weights (eq. 7-8);
the L2 cost (eq. 6, p = 2) becomes μᵀGμ - 2bᵀμ + yᵀy in the monomials μ, minimised exactly
(SQP on its exact Hessian by default), with no more rendering.

The method is built in stages, each a sub-package that imports only the stages below it
(pyproject.toml's import-linter contract), lowest first: ``trace`` (the device's path loop),
``system`` (the pass and its Gram systems), ``survey`` and ``misfit`` (the survey's unknowns; what
the model does not explain), ``uncertainty``, ``fit`` (the solves of one pass) and ``loop`` (the
passes and the result); each ``__init__`` says what enters the stage and what leaves it. The
options (:mod:`methods.symbolic.options`) are below them all; this module registers the method.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from framework.config import method_defaults
from framework.errors import ConfigError
from framework.options import build
from framework.registry import Method, MethodResult, register
from methods._common import Trace, initial_guess
from methods.symbolic.fit.field import FieldOptions
from methods.symbolic.fit.fit import images_at
from methods.symbolic.loop.outputs import method_result
from methods.symbolic.loop.refinement import render_pass, run_passes
from methods.symbolic.loop.resolved import resolve
from methods.symbolic.options import SolverOptions, SymbolicOptions
from methods.symbolic.survey.illumination import check_gauge, nominal, pass_basis
from methods.symbolic.survey.known import known_guess, warn_unseen
from methods.symbolic.system.emitter_groups import unknown_emitters
from methods.symbolic.system.polynomial_pass import release_pass_scene


@register("symbolic")
class SymbolicMethod(Method):
    """Symbolic-ray-tracing inversion of the kernel weights ρ (paper sections 4.2-4.4).

    One polynomial pass renders every selected view once and keeps each pixel as a polynomial
    in ρ (eq. 7-8; :class:`~methods.symbolic.trace.integrator.PolynomialPathIntegrator`); the L2 cost
    (eq. 6, p = 2) becomes ``μᵀGμ - 2bᵀμ + yᵀy`` in the monomials μ and is minimised exactly
    (:mod:`methods.symbolic.fit.joint`, or :mod:`methods.symbolic.fit.per_segment` with
    ``method.cost=per_segment``), with no more rendering. By default the pass also traces
    ``render.tail_bounces`` reflections beyond N_max weighted by the guesses, and further passes
    are rendered at the estimate until it stops moving (:mod:`methods.symbolic.loop.refinement`).
    Field photographs (pixel weights, per-view exposure gains, a lens's vignetting, robust
    reweighting) are fitted from the same stored coefficients (:mod:`methods.symbolic.fit.field`,
    :mod:`methods.symbolic.survey.vignetting`). An emitter of unknown scale (scene.yaml ``scale:
    unknown``) is one more variable of the pass's polynomials, solved with ρ
    (:mod:`methods.symbolic.survey.illumination`; refused when every emitter is unknown and no segment
    is ``known``, and with ``method.cost=per_segment``).

    Options: :class:`~methods.symbolic.options.SymbolicOptions` (each option's
    default on its field; ``framework/conf/method/symbolic.yaml`` and docs/cli.md's table are generated
    from them). Uses
    ``render.spp``, ``render.max_bounces`` (N_max), ``render.tail_bounces``, ``seed``,
    ``executor`` and ``cache.dir`` of the run.

    Uncertainty (:mod:`methods.symbolic.uncertainty`): parameters no pixel depends on are
    ``observable`` False (estimate and std NaN) and left out of the solve; ``extras`` holds the
    formula of ``std`` (``std_method``), the correlation of the observable parameters, and which
    parameters are ill-determined (std above 0.05 or NaN); docs/results.md lists every extra.

    Known weights (scene.yaml ``known``, a calibration panel; :mod:`methods.symbolic.survey.known`): the
    pass renders them as variables at their values, the solve substitutes the values (they are
    not parameters of the solve); they are reported with their value, std 0, ``"known": true``.
    A known kernel outside ``method.kernels`` (``lambertian_prior``: a known specular) is left
    out like that method's other kernels (weight 0 in its model).

    Limitations: kernel BRDFs only (paper section 4.3). The solve costs O(nnz(G)) per evaluation
    and O(D²) memory per Hessian. The PSD projection is exact on each connected component of G
    of at most :data:`~methods.symbolic.system.gram.PSD_BLOCK_LIMIT` monomials; larger components are
    left unprojected (a log warning, and their sizes in ``extras["psd_skipped_components"]``).
    Neither std covers the bias of observations holding more than N_max reflections with
    ``render.tail_bounces=0``, nor that of ``gram: plain``.
    """

    Options = SymbolicOptions
    #: a segment's ``known`` weights are substituted in the solve (:mod:`methods.symbolic.survey.known`);
    #: scene.yaml's ``photometry: vignetting`` is applied or estimated
    #: (:mod:`methods.symbolic.survey.vignetting`)
    #: an emitter's ``scale: unknown`` is estimated with ρ (:mod:`methods.symbolic.survey.illumination`)
    survey = frozenset({"known", "vignetting", "scale"})
    kernels: tuple[str, ...] | None = None     # fixed by subclasses (lambertian_prior)

    @classmethod
    def check_options(cls, options: SymbolicOptions) -> SymbolicOptions:
        """The per-segment fit runs its own block sweeps (SQP from the guess, stopped by
        ``solver.xtol_rel``): a joint-solver option set away from its shipped value would not be
        used, so it is refused rather than ignored."""
        if options.cost == "per_segment":
            shipped = _shipped_solver()
            for key in JOINT_SOLVER_ONLY:
                value = getattr(options.solver, key)
                if value != getattr(shipped, key) and not (key == "starts" and value == 1):   # one start: its own
                    raise ConfigError(f"method.solver.{key}={value} is not used by method.cost=per_segment (its "
                                      "block sweeps are SQP from the guess, stopped by method.solver.xtol_rel): "
                                      f"leave it at {getattr(shipped, key)}, or use method.cost=joint")
        return options

    def parameters(self, problem):
        return problem.scene.parameters(kernels=self.kernels or self.options.kernels)

    def check_problem(self, problem) -> None:
        # a reference view outside the views
        FieldOptions.resolve(resolve(self.options, problem).options, problem, boundaries=False)
        if self.options.bias == "richardson" and problem.settings.spp % 4:
            raise ConfigError(f"render.spp={problem.settings.spp}: method.bias=richardson splits each pixel's samples "
                              "in four quarters; give a multiple of 4")
        if unknown_emitters(problem.scene):
            check_gauge(problem.scene)                                  # ρ and the light's scale trade off
            if self.options.cost == "per_segment":
                raise ConfigError("method.cost=per_segment cannot estimate an emitter's unknown scale (it couples "
                                  "every segment's block): use method.cost=joint, or give the scale as a number")
        warn_unseen(problem, self.parameters(problem))                  # a known segment no view sees

    def _start(self, problem):
        """``(parameters, the problem over them, start weights, renders spent on them)``."""
        params = self.parameters(problem)
        sub = dataclasses.replace(problem, parameters=params)
        x0, renders = initial_guess(self.options, sub, prior=_lambertian_prior)
        return params, sub, known_guess(x0, params, problem.scene), renders   # a known weight starts at its value

    def run(self, problem) -> MethodResult:
        t0 = time.perf_counter()
        params, sub, x0, renders = self._start(problem)
        trace = Trace(t0)
        trace.record(renders, x0)
        try:
            passes = run_passes(sub, params, x0, self.options, renders=renders, trace=trace)
        finally:
            release_pass_scene()            # the next run starts with the same objects alive
        return method_result(passes, sub, params, x0, self.options, started=t0, trace=trace)

    def render_at(self, problem, rho: np.ndarray, *, seed: int = 0) -> dict[str, np.ndarray]:
        """One polynomial pass at the initial guess, evaluated at ρ (restricted to this method's
        kernels): the images the solve compares with the observations."""
        index = {(p.segment, p.kernel): p.index for p in problem.parameters}
        params, sub, x0, _ = self._start(problem)
        try:
            result = render_pass(sub, params, x0, self.options, seed=seed)
        finally:
            release_pass_scene()            # as run(): the next run starts with the same objects alive
        basis = pass_basis(len(params), problem.settings.max_bounces, problem.scene, result.codes)
        own = rho[[index[(p.segment, p.kernel)] for p in params]]
        return images_at(result, basis, nominal(own, problem.scene), problem.cameras)   # the declared light


#: ``method.solver`` options the per-segment fit does not use
JOINT_SOLVER_ONLY = ("algorithm", "starts", "max_eval", "ftol_rel", "precondition")


def _shipped_solver() -> SolverOptions:
    """``method.solver`` as shipped (its fields' defaults; every symbolic preset keeps them)."""
    return build(SolverOptions, {}, section="method.solver")


def _lambertian_prior(problem) -> MethodResult:
    """``method.init=lambertian_prior``: the symbolic inversion of the diffuse weights with the
    ``lambertian_prior`` method's shipped options but one pass (a start needs no refinement;
    that method is this class with diffuse kernels) and the joint cost (:func:`prior_config`)."""
    return SymbolicMethod(prior_config()).run(problem)


def prior_config() -> SymbolicOptions:
    """The ``lambertian_prior`` method's shipped options with ``refine: 0`` and ``cost: joint``:
    the one-pass prior that ``method.init=lambertian_prior`` starts from
    (:func:`methods._common.initial_guess`). Joint, because the fits it starts minimise the joint
    cost: measured on the small street, all views, seeds 0-3 (tests/methods/test_inversion.py), the
    kernel solve from the joint prior took 30, 30, 25, 45 evaluations, from the per-segment
    prior 62, 33, 27, 34 (flat guess: 31, 29, 28, 59), with the same errors (mean 0.0166 and
    0.0167)."""
    shipped = build(SymbolicOptions, method_defaults("lambertian_prior"))
    return dataclasses.replace(shipped, refine=0, cost="joint")
