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
from framework.methods import Method, MethodResult, register
from methods._common import check_choice, check_number, initial_guess, segment_groups
from methods.symbolic.basis import MonomialBasis
from methods.symbolic.polynomial_pass import polynomial_pass
from methods.symbolic.solve import solve_polynomial


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
    memory_mb : float > 0, default 512
        Memory for the coefficient tiles of the pass; sets the tile size.
    solver.algorithm, solver.starts, solver.max_eval, solver.xtol_rel
        nlopt settings (``LD_SLSQP``: takes the per-segment Σρ <= 1 constraints).

    Uses ``render.spp``, ``render.max_bounces`` (N_max) and ``seed`` of the main config.
    Limitations: kernel BRDFs only (paper section 4.3); N_e = C(D + N_max, N_max) monomials,
    so the solve costs O(N_e²) per evaluation.
    """

    kernels: tuple[str, ...] | None = None     # fixed by subclasses (lambertian_prior)

    def parameters(self, problem):
        kernels = self.kernels
        if kernels is None and self.cfg.get("kernels", "all") != "all":
            kernels = tuple(self.cfg.kernels)
        return problem.scene.parameters(kernels=kernels)

    def check(self):
        check_number(self.cfg, "prob_floor", 0.0, 1.0)
        check_number(self.cfg, "memory_mb", 0.0, lo_open=True)
        check_number(self.cfg.solver, "starts", 1, integer=True)
        check_choice(self.cfg.solver, "algorithm", ("LD_SLSQP", "LD_MMA", "LD_CCSAQ"))

    def run(self, problem) -> MethodResult:
        self.check()
        t0 = time.perf_counter()
        params = self.parameters(problem)
        sub = dataclasses.replace(problem, parameters=params)
        x0, renders = initial_guess(self.cfg, sub)
        settings = problem.settings
        basis = MonomialBasis(len(params), int(settings.render.max_bounces))
        result = polynomial_pass(sub, params, x0, basis, spp=int(settings.render.spp),
                                 seed=int(problem.seed) + 7777 * renders, prob_floor=float(self.cfg.prob_floor),
                                 memory_mb=float(self.cfg.memory_mb), cache=Cache(settings.cache.dir))
        solver = self.cfg.solver
        sol = solve_polynomial(result.system, basis, segments_params=segment_groups(params), x0=x0,
                               algorithm=str(solver.algorithm), starts=int(solver.starts),
                               max_eval=int(solver.max_eval), xtol_rel=float(solver.xtol_rel),
                               seed=int(problem.seed))
        mu = np.stack([basis.evaluate(sol.estimate[:, c]) for c in range(problem.n_channels)])
        recon = {cam.name: result.image(cam.name, mu, (cam.height, cam.width)) for cam in problem.cameras}
        return MethodResult(
            estimate=sol.estimate, renders=renders + 1, parameters=params, reconstructions=recon,
            timings_s={"render": result.render_s, "solve": sol.solve_s,
                       "method": time.perf_counter() - t0},
            cost_history=list(sol.cost_history), cost_times_s=list(sol.eval_times_s),
            extras={"n_monomials": basis.size, "solver_evaluations": sol.n_evals,
                    "initial_guess": x0.tolist(), "views_from_cache": result.from_cache})
