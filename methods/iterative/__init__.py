"""The paper's plain algorithm (figure 2): render, compare, finite-difference gradient, repeat."""
from __future__ import annotations

import time

import numpy as np

from framework.observe import inversion_seed
from framework.optim import StopOptimization, check_algorithm, minimize
from framework.registry import MethodResult, Problem, register
from framework.render.mitsuba_scene import MitsubaScene
from methods import _common as C
from methods.iterative.options import IterativeOptions
from methods.lambertian_prior import lambertian_prior


@register("iterative")
class IterativeMethod(C.RenderingBaseline):
    r"""Plain iterative inversion: every cost evaluation is a new Mitsuba rendering.

    This is the baseline of the paper's section 4.1 (figure 2). The cost is eq. 6 with
    :math:`p = 2`, squared,

    .. math:: \epsilon(\rho) = \sum_{\text{view } j} \sum_{\text{pixel } i} \sum_{\text{channel } c}
              [L^{\text{synthetic}}_c(i, j, \rho) - L^{\text{acquired}}_c(i, j)]^2 ,

    where :math:`L^{\text{synthetic}}` is a fresh Mitsuba ``path`` rendering (``max_depth =
    render.max_bounces + render.tail_bounces + 1``: every reflection the symbolic pass traces, so
    the methods compare like with like; box filter, ``render.spp`` samples per pixel) of every selected
    view with the weights ρ written into the scene in place (no reload). The gradient is
    estimated by finite differences. The channels are independent problems, so one render with
    parameter :math:`k` perturbed in *every* channel at once gives :math:`\partial\epsilon_c /
    \partial\rho_{k,c}` for all channels :math:`c`: a forward-difference gradient costs
    :math:`D + 1` renders and a central one :math:`2D + 1`, with :math:`D` the number of
    (segment, kernel) parameters. All channels are optimised jointly by nlopt on
    :math:`x = \mathrm{vec}(\rho)` (``P × C``), under bounds :math:`0 \le \rho \le 1` and, per
    segment and channel, :math:`\sum_\text{kernels} \rho \le 1` (:func:`framework.optim.minimize`).

    One *render* is one full pass over the selected views (``docs/results.md``). The run stops before a
    cost (and gradient) evaluation that would leave no render for the final reconstruction under
    ``budget.renders``, and returns the best ρ evaluated so far. A forward-difference run spends
    at most ``evaluations × (D + 1) + 1`` renders (the ``+ 1`` is the final reconstruction;
    evaluations nlopt asks for without a gradient cost one render).

    Options: :class:`~methods.iterative.options.IterativeOptions` (each option's
    default on its field; ``framework/conf/method/iterative.yaml`` and docs/cli.md's table are generated
    from them).

    Limitations
    -----------
    With ``noise: fresh`` the finite differences of two independent Monte-Carlo estimates are
    dominated by noise unless ``render.spp`` is large compared with ``1 / step²``: the
    instability the paper's section 4.2 describes. The cost of one evaluation grows linearly
    with the number of parameters.
    """

    Options = IterativeOptions

    def check_problem(self, problem) -> None:
        super().check_problem(problem)
        several = any(len(g) > 1 for g in C.segment_groups(problem.parameters))
        check_algorithm(self.options.algorithm, constrained=several, key="method.algorithm")

    def run(self, problem: Problem) -> MethodResult:
        opts = self.options
        t0, rho0, ledger = self._start(problem, lambertian_prior)
        objective = _Objective(problem, ledger, opts, trace=C.Trace(t0))
        objective.trace.record(ledger.used, rho0)
        try:
            best_x, status = _optimise(objective, rho0, problem, opts)
            rho = best_x.reshape(rho0.shape)
            recon = objective.final_render(rho)
        finally:
            ledger.close()
        return C.loop_result(
            problem, ledger, started=t0, rho=rho, costs=objective.costs, times=objective.times, trace=objective.trace,
            reconstructions=recon,
            extras={"status": status, "evaluations": len(objective.costs),
                    "gradient_evaluations": objective.n_grad, "renders_per_gradient": objective.grad_renders,
                    "fd": opts.fd, "step": opts.step, "noise": opts.noise})

    def render_at(self, problem: Problem, rho: np.ndarray, *, seed: int = 0) -> dict[str, np.ndarray]:
        """One pass of the objective's own renderer (what every cost evaluation renders)."""
        return C.render_once(problem, seed, "iterative render",
                             lambda pb, ledger: _Objective(pb, ledger, self.options).render(rho))


def _optimise(objective: "_Objective", rho0: np.ndarray, problem: Problem, opts: IterativeOptions) -> tuple[np.ndarray, str]:
    """nlopt over vec(ρ); (best x seen, status). Returns ρ0 untouched if no evaluation fits the budget."""
    if not objective.affordable(need_grad=True):
        return rho0.ravel(), "BUDGET_TOO_SMALL"
    res = minimize(objective, rho0.ravel(), lower=0.0, upper=1.0,
                   inequality_groups=C.flat_constraint_groups(problem.parameters, problem.n_channels),
                   algorithm=opts.algorithm, max_eval=opts.max_eval,
                   xtol_rel=opts.xtol_rel, ftol_rel=opts.ftol_rel)
    return res.x, res.status


class _Objective:
    """``(x, need_grad) -> (cost, gradient)`` by re-rendering; counts renders, records costs."""

    def __init__(self, problem: Problem, ledger: C.RenderLedger, opts: IterativeOptions, *, trace: C.Trace | None = None):
        self.problem, self.ledger, self.opts = problem, ledger, opts
        self.spp = problem.settings.spp
        self.ms = MitsubaScene(problem.scene, problem.cameras, spp=self.spp,
                               integrator={"type": "path", "max_depth": C.max_depth(problem)})
        self.observed = C.observed_list(problem)
        self.weights = C.weights_list(problem)         # the scene's pixel weights, or None
        self.shape = (len(problem.parameters), problem.n_channels)
        self.grad_renders = len(problem.parameters) * (2 if opts.fd == "central" else 1)
        self.costs: list[float] = []
        self.times: list[float] = []     # seconds since the method started, at each evaluation
        self.trace = trace or C.Trace(time.perf_counter())
        self._best = (np.inf, None)      # nlopt returns the best point evaluated: so does the trace
        self.n_grad = 0
        self._counter = 0

    def affordable(self, *, need_grad: bool) -> bool:
        """Whether one evaluation still leaves a render for the final reconstruction."""
        return self.ledger.can_afford(1 + (self.grad_renders if need_grad else 0) + 1)

    def __call__(self, x: np.ndarray, need_grad: bool):
        if not self.affordable(need_grad=need_grad):
            raise StopOptimization
        rho = np.asarray(x, dtype=float).reshape(self.shape)
        base = self.channel_costs(rho)
        grad = self.gradient(rho, base) if need_grad else None
        self.costs.append(float(base.sum()))
        self.times.append(time.perf_counter() - self.trace.started)
        if self.costs[-1] < self._best[0]:
            self._best = (self.costs[-1], rho.copy())
        self.trace.record(self.ledger.used, self._best[1])
        return float(base.sum()), grad

    def channel_costs(self, rho: np.ndarray) -> np.ndarray:
        """(C,) cost of one full pass at ρ."""
        return C.channel_costs(self.render(rho), self.observed, self.weights)

    def render(self, rho: np.ndarray) -> list[np.ndarray]:
        self.ms.set_weights(rho, self.problem.parameters)
        return C.render_pass(self.ms, spp=self.spp, seeds=self.seeds(), ledger=self.ledger)

    def seeds(self) -> list[int]:
        """Per-view Mitsuba seeds of the next pass (fresh: never reused; fixed: the same every pass)."""
        n = len(self.problem.cameras)
        start = self._counter if self.opts.noise == "fresh" else 0
        self._counter += n
        return [inversion_seed(self.problem.seed, start + v) for v in range(n)]

    def gradient(self, rho: np.ndarray, base: np.ndarray) -> np.ndarray:
        """(P·C,) finite-difference gradient: one perturbed pass per parameter (two if central)."""
        self.n_grad += 1
        grad = np.empty(self.shape)
        for k in range(self.shape[0]):
            grad[k] = self._forward(rho, k, base) if self.opts.fd == "forward" else self._central(rho, k)
        return grad.ravel()

    def _forward(self, rho: np.ndarray, k: int, base: np.ndarray) -> np.ndarray:
        step = self.opts.step
        h = np.where(rho[k] + step <= 1.0, step, -step)
        return (self.channel_costs(_perturbed(rho, k, rho[k] + h)) - base) / h

    def _central(self, rho: np.ndarray, k: int) -> np.ndarray:
        step = self.opts.step
        hi, lo = np.minimum(rho[k] + step, 1.0), np.maximum(rho[k] - step, 0.0)
        return (self.channel_costs(_perturbed(rho, k, hi)) - self.channel_costs(_perturbed(rho, k, lo))) / (hi - lo)

    def final_render(self, rho: np.ndarray) -> tuple[list, list | None]:
        """The reconstructions at the estimate and their Monte Carlo variances
        (:func:`methods._common.reconstruction_pass`, one render); none if the budget is spent."""
        if not self.ledger.can_afford(1):
            return [], None
        self.ms.set_weights(rho, self.problem.parameters)
        return C.reconstruction_pass(self.ms, spp=self.spp, seeds=self.seeds(), ledger=self.ledger)


def _perturbed(rho: np.ndarray, k: int, row: np.ndarray) -> np.ndarray:
    out = rho.copy()
    out[k] = row
    return out
