"""solve_polynomial / hessian on synthetic polynomial systems with known minimisers."""
import numpy as np
import pytest

from framework.errors import ConfigError
from methods.symbolic.fit.solve import solve_polynomial
from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.cost import channel_cost_grad, hessian
from methods.symbolic.system.gram import GramSystem


def _system(rho_true, seed=0, n=400, N=3):
    """Noise-free pixels y = γ·μ(ρ_true) with random sparse γ: ρ_true is an exact minimiser (cost 0)."""
    D, C = rho_true.shape
    b = MonomialBasis(D, N)
    rng = np.random.default_rng(seed)
    X = rng.uniform(0, 1, (n, b.size, C)) * (rng.uniform(size=(n, b.size, 1)) < 0.3)
    X[:, 1:D + 1] += rng.uniform(0, 1, (n, D, C))      # every parameter observable
    y = np.stack([X[:, :, c] @ b.evaluate(rho_true[:, c]) for c in range(C)], -1)
    return GramSystem.zeros(b.size, C).accumulate(X, y), b


def test_recovers_interior_minimiser():
    """Known feasible minimiser recovered to 1e-6 from x0 = 0.5 (all channels), cost ~ 0."""
    rho = np.array([[0.3, 0.2, 0.05], [0.4, 0.1, 0.5], [0.6, 0.7, 0.9]])
    s, b = _system(rho)
    r = solve_polynomial(s, b, segments_params=[[0, 1], [2]], x0=np.full((3, 3), 0.5))
    np.testing.assert_allclose(r.estimate, rho, atol=1e-6)
    assert np.all(r.cost < 1e-8 * s.yy)
    assert r.n_evals == len(r.cost_history) == len(r.eval_times_s) and r.solve_s > 0
    assert r.cost_history[-1] <= r.cost_history[0]


def test_constraint_active_when_unconstrained_minimum_violates_it():
    """ρ_true = (0.7, 0.6) on a segment: Σ ρ = 1.3 > 1, so the estimate lies on Σ ρ = 1 (to 1e-8)
    and is no worse than any feasible point sampled on that line (brute force, 2001 points)."""
    rho = np.array([[0.7], [0.6], [0.5]])
    s, b = _system(rho, seed=1)
    r = solve_polynomial(s, b, segments_params=[[0, 1], [2]], x0=np.full((3, 1), 0.3))
    est = r.estimate[:, 0]
    assert est[0] + est[1] <= 1 + 1e-8 and est[0] + est[1] >= 1 - 1e-6
    assert np.all(est >= 0) and np.all(est <= 1)
    t = np.linspace(0, 1, 2001)
    brute = min(channel_cost_grad(s, b, 0, np.array([a, 1 - a, est[2]]))[0] for a in t)
    assert r.cost[0] <= brute + 1e-9 * max(1.0, brute)


def test_gradient_and_hessian_exact():
    """Analytic gradient / Hessian vs central differences of the cost (rel. 1e-5)."""
    rho = np.array([[0.3], [0.4], [0.6]])
    s, b = _system(rho, seed=2)
    x = np.array([0.5, 0.2, 0.35])
    f, g = channel_cost_grad(s, b, 0, x)
    H = hessian(s, b, x[:, None])[0]
    h = 1e-5
    for k in range(3):
        e = np.zeros(3); e[k] = h
        fd = (channel_cost_grad(s, b, 0, x + e)[0] - channel_cost_grad(s, b, 0, x - e)[0]) / (2 * h)
        assert fd == pytest.approx(g[k], rel=1e-5)
        fdh = (channel_cost_grad(s, b, 0, x + e)[1] - channel_cost_grad(s, b, 0, x - e)[1]) / (2 * h)
        np.testing.assert_allclose(H[:, k], fdh, rtol=1e-5, atol=1e-6 * np.abs(H).max())


def test_rejects_unconstrained_algorithm():
    s, b = _system(np.array([[0.3], [0.4], [0.6]]))
    with pytest.raises(ConfigError, match="LD_LBFGS"):
        solve_polynomial(s, b, segments_params=[[0, 1], [2]], x0=np.full(3, 0.5), algorithm="LD_LBFGS")


def test_preconditioned_solve_same_minimum_fewer_evaluations():
    """nlopt's SLSQP with precondition=True (Hessian metric) and False reach the same minimiser (to
    1e-6) and cost (relative 1e-9); the preconditioned solve needs fewer evaluations, all starts
    together (SQP, the default, uses the Hessian itself)."""
    rho = np.array([[0.3, 0.2, 0.05], [0.4, 0.1, 0.5], [0.6, 0.7, 0.9]])
    s, b = _system(rho, seed=3)
    runs = [solve_polynomial(s, b, segments_params=[[0, 1], [2]], x0=np.full((3, 3), 0.5), precondition=p,
                             algorithm="LD_SLSQP") for p in (False, True)]
    np.testing.assert_allclose(runs[1].estimate, runs[0].estimate, atol=1e-6)
    np.testing.assert_allclose(runs[1].cost, runs[0].cost, rtol=1e-9, atol=1e-12 * s.yy.max())
    assert runs[1].n_evals < runs[0].n_evals


def test_metric_is_hessian_when_positive_definite():
    """At the minimiser of a noise-free system the residual is zero, so the Hessian is its
    Gauss-Newton part, and here PD: metric == hessian."""
    from methods.symbolic.system.cost import ChannelCost
    rho = np.array([[0.3], [0.4], [0.6]])
    s, b = _system(rho, seed=2)
    cost = ChannelCost(s, b, 0)
    x = rho[:, 0]
    assert np.linalg.eigvalsh(cost.hessian(x))[0] > 0
    np.testing.assert_allclose(cost.metric(x), cost.hessian(x))
    np.testing.assert_allclose(cost.hessian(x), cost.gauss_newton(x), atol=1e-8 * np.abs(cost.hessian(x)).max())


def test_metric_falls_back_to_gauss_newton():
    """One pixel ρ0·ρ1 observed as 1: f = (ab - 1)². By hand, at a = b = 0.1 the Hessian
    [[2b², 4ab - 2], [4ab - 2, 2a²]] = [[0.02, -1.96], [-1.96, 0.02]] is indefinite, and the
    metric is the Gauss-Newton part 2JᵀJ with J = (b, a): [[0.02, 0.02], [0.02, 0.02]]."""
    from methods.symbolic.system.cost import ChannelCost
    basis = MonomialBasis(2, 2)
    gamma = np.zeros((1, basis.size, 1))
    gamma[0, basis.index([0, 1]), 0] = 1.0
    cost = ChannelCost(GramSystem.zeros(basis.size, 1).accumulate(gamma, np.ones((1, 1))), basis, 0)
    x = np.array([0.1, 0.1])
    np.testing.assert_allclose(cost.hessian(x), [[0.02, -1.96], [-1.96, 0.02]], atol=1e-12)
    np.testing.assert_allclose(cost.metric(x), [[0.02, 0.02], [0.02, 0.02]], atol=1e-12)


def test_sqp_and_slsqp_same_minimiser():
    """Noisy pixels (no exact minimiser) and ρ_true with Σ > 1 on the first segment (the optimum on
    the constraint): the SQP solve and nlopt's LD_SLSQP end within 1e-7 of each other, and SQP's
    cost is not higher (beyond 1e-10 relative)."""
    rho = np.array([[0.7, 0.3], [0.6, 0.2], [0.5, 0.8]])
    s, b = _system(rho, seed=3)
    s.b = s.b * 1.03                                   # inconsistent: the observations moved by 3 %
    kw = dict(segments_params=[[0, 1], [2]], x0=np.full((3, 2), 0.4))
    sqp, ref = (solve_polynomial(s, b, algorithm=a, **kw) for a in ("SQP", "LD_SLSQP"))
    np.testing.assert_allclose(sqp.estimate, ref.estimate, atol=1e-7)
    assert np.all(sqp.cost <= ref.cost + 1e-10 * np.abs(ref.cost))


def test_solve_hands_its_last_hessian_to_the_std():
    """Where a channel's SQP ends on a Hessian of its estimate, ``SolveResult.hessians`` holds it:
    equal to :func:`hessian` recomputed there to 1e-12 relative (the same sums), and the standard
    errors from it equal those recomputed."""
    from methods.symbolic.uncertainty.standard_errors import parameter_uncertainty
    rho = np.array([[0.7, 0.3], [0.6, 0.2], [0.5, 0.8]])
    s, b = _system(rho, seed=3)
    s.b = s.b * 1.03
    r = solve_polynomial(s, b, segments_params=[[0, 1], [2]], x0=np.full((3, 2), 0.4), starts=1)
    assert len(r.hessians) == 2 and all(h is not None for h in r.hessians)
    again = hessian(s, b, r.estimate)
    np.testing.assert_allclose(np.stack(r.hessians), again, rtol=1e-12, atol=1e-12 * np.abs(again).max())
    known = parameter_uncertainty(s, b, r.estimate, hessians=r.hessians)
    fresh = parameter_uncertainty(s, b, r.estimate)
    np.testing.assert_allclose(known.std, fresh.std, rtol=1e-10)


def test_hessian_known_errors():
    rho = np.array([[0.3], [0.4], [0.6]])
    s, b = _system(rho, seed=2)
    with pytest.raises(ValueError, match="known has 2 entries for 1 channels"):
        hessian(s, b, rho, known=[None, None])
