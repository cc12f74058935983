"""Differentiable rendering baseline: path replay backpropagation (``prb_dirac``) and Adam."""
from __future__ import annotations

import time

import numpy as np

from framework.observe import inversion_seed
from framework.registry import MethodResult, Problem, register
from framework.render.mitsuba_scene import MitsubaScene
from methods import _common as C
from methods.differentiable.integrator import integrator_dict
from methods.differentiable.options import DifferentiableOptions
from methods.lambertian_prior import lambertian_prior


@register("differentiable")
class DifferentiableMethod(C.RenderingBaseline):
    r"""Inverse rendering as most people would do it today: differentiable path tracing + Adam.

    Each iteration renders every selected view with the ``prb_dirac`` integrator
    (:class:`methods.differentiable.integrator.DiracPRBMixin`: Mitsuba's path replay
    backpropagation ``prb``, whose adjoint also differentiates the sample weight of Dirac
    lobes; ``max_depth = render.max_bounces + render.tail_bounces + 1``) at the current
    weights ρ and back-propagates the same cost as the other methods, eq. 6 with
    :math:`p = 2`, squared,

    .. math:: \epsilon(\rho) = \sum_{j} \sum_{i} \sum_{c}
              [L^{\text{synthetic}}_c(i, j, \rho) - L^{\text{acquired}}_c(i, j)]^2 ,

    to one optimisation variable per (segment, kernel) parameter and channel. That variable is
    written as it is into the exact kernel-sum BSDF Σ ρ_i f_i of *every* mesh of the segment
    (:meth:`framework.render.mitsuba_scene.MitsubaScene.assign_weights`, the same writer every
    method uses), so the gradients of all its meshes accumulate into it. ρ is updated with Adam
    (Kingma & Ba 2015; a small host-side implementation, bias-corrected) and then projected
    onto the feasible set: clipped to [0, 1], then, per segment and channel where
    :math:`\sum_\text{kernels} \rho > 1`, the exact Euclidean projection onto the simplex face
    :math:`\sum \rho = 1` (:func:`methods._common.project_feasible`).

    The primal and gradient passes of an iteration use fresh seeds
    (``inversion_seed(seed, ·)``, decorrelated from each other and from the observations).
    One iteration costs **two renders** (a forward and a backward pass over all views);
    the final reconstruction at the estimate costs one more. The run stops at ``iterations``
    or when the next iteration would leave no render for the reconstruction under
    ``budget.renders``. The estimate is the last iterate (Adam's iterates are noisy; the
    recorded cost of each iteration is the Monte-Carlo cost of its primal render).

    Options: :class:`~methods.differentiable.options.DifferentiableOptions` (each option's
    default on its field; ``framework/conf/method/differentiable.yaml`` and docs/cli.md's table are generated
    from them).
    The learning rate's default is the best of the benchmark's sweep (BENCHMARKS.md, the
    comparison section); on diffuse-only scenes a smaller rate has the smaller noise ball.

    Every weight gets a gradient, Dirac-lobe kernels (``specular``, a perfect mirror)
    included: Mitsuba's own ``prb`` gives those none (it attaches the gradient through
    ``bsdf.eval``, which is 0 on a Dirac lobe) and, on a segment mixing a mirror with a smooth
    kernel, biases the smooth weights' gradients (it differentiates the smooth kernels'
    value at the mirror direction); ``prb_dirac`` differentiates the sample weight there
    instead (``tests/methods/test_differentiable_gradients.py`` checks both against finite
    differences).

    Limitations
    -----------
    Adam with a constant learning rate ends in a noise ball of radius about ``lr``; lower
    ``lr`` and raise the budget for a tighter estimate.
    """

    Options = DifferentiableOptions

    def run(self, problem: Problem) -> MethodResult:
        opts = self.options
        t0, rho, ledger = self._start(problem, lambertian_prior)
        try:
            fit = _Fit(problem, ledger, opts, trace=C.Trace(t0))
            fit.trace.record(ledger.used, rho)
            rho = fit.optimise(rho)
            recon = fit.final_render(rho)
        finally:
            ledger.close()
        return C.loop_result(
            problem, ledger, started=t0, rho=rho, costs=fit.costs, times=fit.times, reconstructions=recon,
            trace=fit.trace,
            extras={"iterations": len(fit.costs), "lr": opts.lr, "spp": fit.spp,
                    "spp_grad": fit.spp_grad, "projection": "clip + simplex face"})

    def render_at(self, problem: Problem, rho: np.ndarray, *, seed: int = 0) -> dict[str, np.ndarray]:
        """The primal pass of the fit's own AD renderer at ρ, weights written as the fit writes them."""
        return C.render_once(problem, seed, "differentiable render",
                             lambda pb, ledger: _Fit(pb, ledger, self.options).final_render(rho)[0])


class _Adam:
    """Adam on a numpy array (bias-corrected moments)."""

    def __init__(self, shape, *, lr: float, beta1: float, beta2: float, eps: float = 1e-8):
        self.lr, self.b1, self.b2, self.eps = lr, beta1, beta2, eps
        self.m, self.v, self.t = np.zeros(shape), np.zeros(shape), 0

    def step(self, x: np.ndarray, grad: np.ndarray) -> np.ndarray:
        self.t += 1
        self.m = self.b1 * self.m + (1 - self.b1) * grad
        self.v = self.b2 * self.v + (1 - self.b2) * grad ** 2
        m_hat = self.m / (1 - self.b1 ** self.t)
        v_hat = self.v / (1 - self.b2 ** self.t)
        return x - self.lr * m_hat / (np.sqrt(v_hat) + self.eps)


class _Fit:
    """The Mitsuba scene with a ``prb_dirac`` integrator, its weight keys, and the optimisation loop."""

    def __init__(self, problem: Problem, ledger: C.RenderLedger, opts: DifferentiableOptions, *, trace: C.Trace | None = None):
        self.problem, self.ledger, self.opts = problem, ledger, opts
        self.spp = problem.settings.spp
        self.spp_grad = self.spp if opts.spp_grad is None else opts.spp_grad
        self.ms = MitsubaScene(problem.scene, problem.cameras, spp=self.spp,
                               integrator=integrator_dict(C.max_depth(problem)))
        self.observed = C.observed_list(problem)
        self.weights = C.weights_list(problem)         # the scene's pixel weights, or None
        self.costs: list[float] = []
        self.times: list[float] = []     # seconds since the method started, at each iteration
        self.trace = trace or C.Trace(time.perf_counter())
        self._targets = _device_targets(self.observed, self.weights)

    def optimise(self, rho: np.ndarray) -> np.ndarray:
        """Adam + projection until ``iterations`` or the budget (keeping one render for the end)."""
        adam = _Adam(rho.shape, lr=self.opts.lr, beta1=self.opts.beta1, beta2=self.opts.beta2)
        for it in range(self.opts.iterations):
            if not self.ledger.can_afford(2 + 1):
                break
            cost, grad = self.cost_and_gradient(rho, it)
            rho = C.project_feasible(adam.step(rho, grad), self.problem.parameters)
            self.costs.append(cost)
            self.times.append(time.perf_counter() - self.trace.started)
            self.trace.record(self.ledger.used, rho)     # Adam's estimate is its last iterate
        return rho

    def cost_and_gradient(self, rho: np.ndarray, it: int) -> tuple[float, np.ndarray]:
        """Cost at ρ and dε/dρ (P, C), from one forward and one backward pass over the views."""
        import drjit as dr
        import mitsuba as mi
        variables = self.write(rho, grad=True)
        cost, t0 = 0.0, time.perf_counter()
        for v, (obs, pixel_weights) in enumerate(self._targets):
            seed, seed_grad = self.seeds(it, v)
            img = mi.render(self.ms.scene, self.ms.params, sensor=v, spp=self.spp,
                            spp_grad=self.spp_grad, seed=seed, seed_grad=seed_grad)
            residual2 = dr.square(img[..., : obs.shape[-1]] - obs)
            if pixel_weights is not None:                      # masked / saturated pixels: 0
                residual2 = residual2 * pixel_weights
            loss = dr.sum(residual2, axis=None)
            cost += float(loss.array[0])
            dr.backward(loss)
        grad = np.stack([_to_numpy(dr.grad(var), rho.shape[1]) for var in variables])
        self.ledger.spend(2, time.perf_counter() - t0)
        return cost, grad

    def seeds(self, it: int, view: int) -> tuple[int, int]:
        """(primal, gradient) Mitsuba seeds of ``view`` at iteration ``it``: even, never reused."""
        counter = 2 * (it * len(self.observed) + view)
        return inversion_seed(self.problem.seed, counter), inversion_seed(self.problem.seed, counter + 1)

    def write(self, rho: np.ndarray, *, grad: bool) -> list:
        """Write ρ into every mesh's BSDF; with ``grad``, as fresh differentiable variables."""
        import drjit as dr
        variables = [self.ms.weight_value(row) for row in rho]      # opaque: no new kernel per iterate
        for var in variables:
            if grad:
                dr.enable_grad(var)
        self.ms.assign_weights(variables, self.problem.parameters)
        return variables

    def final_render(self, rho: np.ndarray) -> tuple[list, list | None]:
        """The reconstructions at the estimate (primal passes, one render) and their Monte Carlo
        variances (:func:`methods._common.reconstruction_pass`); none if no budget."""
        if not self.ledger.can_afford(1):
            return [], None
        self.write(rho, grad=False)
        seeds = [self.seeds(len(self.costs), v)[0] for v in range(len(self.observed))]
        return C.reconstruction_pass(self.ms, spp=self.spp, seeds=seeds, ledger=self.ledger)


def _device_targets(observed: list[np.ndarray], weights: list | None) -> list[tuple]:
    """Per view, the observed image and the pixel weights (or None) as ``mi.TensorXf``, made once.

    Made once, because Dr.Jit reads a numpy array in place and compiles its alignment into the
    kernel: a fresh array per iteration recompiled the cost kernels whenever it moved."""
    import mitsuba as mi
    weights = weights or [None] * len(observed)
    return [(mi.TensorXf(obs.astype(np.float32)), None if w is None else mi.TensorXf(w.astype(np.float32)))
            for obs, w in zip(observed, weights)]


def _to_numpy(value, n_channels: int) -> np.ndarray:
    return np.broadcast_to(np.array(value, dtype=float).ravel(), (n_channels,)).copy()
