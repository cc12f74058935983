"""framework.optim: the nlopt wrapper, SQP and the feasible set, on small problems solved by hand."""
from __future__ import annotations

import numpy as np
import pytest

from framework.errors import ConfigError


def test_minimize_constrained_quadratic():
    """min |x - t|² with t = (0.8, 0.6): Σ x <= 1 gives (0.6, 0.4) to 1e-6 (analytic)."""
    from framework.optim import minimize
    t = np.array([0.8, 0.6])
    res = minimize(lambda x, g: (float(np.sum((x - t) ** 2)), 2 * (x - t)), np.array([0.5, 0.5]),
                   inequality_groups=[[0, 1]], xtol_rel=1e-10)
    np.testing.assert_allclose(res.x, [0.6, 0.4], atol=1e-6)
    assert res.history and res.f == pytest.approx(min(res.history))


def test_minimize_metric_same_minimum_fewer_evaluations():
    """f = 50(x0 - 0.8)² + 0.5(x1 - 0.6)² on x0 + x1 <= 1. Lagrange (by hand): 100(x0 - 0.8) =
    x1 - 0.6 and x0 + x1 = 1 give x0 = 80.4/101, x1 = 1 - x0. With the exact Hessian as metric
    SLSQP reaches it (to 1e-8) in fewer evaluations than without."""
    from framework.optim import minimize
    t, h = np.array([0.8, 0.6]), np.array([100.0, 1.0])
    f = lambda x, g: (float(0.5 * h @ (x - t) ** 2), h * (x - t))
    runs = [minimize(f, np.array([0.1, 0.1]), inequality_groups=[[0, 1]], xtol_rel=1e-12, ftol_rel=1e-15,
                     metric=m) for m in (None, np.diag(h))]
    for r in runs:
        np.testing.assert_allclose(r.x, [80.4 / 101, 1 - 80.4 / 101], atol=1e-8)
    assert runs[1].n_eval < runs[0].n_eval


def test_minimize_metric_keeps_bounds():
    """Unconstrained minimum (1.5, -0.5) outside [0, 1]²; a rotated metric still stops on the box:
    f = |x - t|² with t = (1.5, -0.5) is minimised on the box at its corner (1, 0) (by hand)."""
    from framework.optim import minimize
    t = np.array([1.5, -0.5])
    metric = np.array([[2.0, 1.0], [1.0, 2.0]])
    r = minimize(lambda x, g: (float(np.sum((x - t) ** 2)), 2 * (x - t)), np.array([0.5, 0.5]),
                 metric=metric, xtol_rel=1e-12)
    np.testing.assert_allclose(r.x, [1.0, 0.0], atol=1e-8)


@pytest.mark.parametrize("metric, algorithm, match", [
    (np.eye(3), "LD_SLSQP", r"metric must be a finite \(2, 2\) matrix"),
    (np.array([[1.0, 0.0], [0.0, np.nan]]), "LD_SLSQP", r"metric must be a finite"),
    (np.zeros((2, 2)), "LD_SLSQP", "metric has no positive eigenvalue"),
    (np.eye(2), "LD_LBFGS", "algorithm=LD_LBFGS with a metric"),
])
def test_minimize_metric_errors(metric, algorithm, match):
    from framework.optim import minimize
    with pytest.raises(ConfigError, match=match):
        minimize(lambda x, g: (0.0, np.zeros(2)), np.zeros(2), metric=metric, algorithm=algorithm)


def test_minimize_stop_keeps_best():
    """StopOptimization after 3 evaluations returns the best point seen, status FORCED_STOP."""
    from framework.optim import StopOptimization, minimize
    calls = []

    def f(x, need):
        if len(calls) == 3:
            raise StopOptimization
        calls.append(x.copy())
        return float(np.sum((x - 0.9) ** 2)), 2 * (x - 0.9)

    res = minimize(f, np.array([0.1, 0.1]), algorithm="LD_LBFGS")
    assert res.status == "FORCED_STOP" and res.n_eval == 3
    assert res.f == min(res.history)


def test_minimize_sqp_projection_by_hand():
    """min ½|x - a|² (Hessian I) on [0, 1]⁴ with x0 + x1 <= 1, a = (0.9, 0.6, 1.4, -0.2): the
    Euclidean projection of a, by hand (0.9 + 0.6 = 1.5 exceeds 1 by 0.5, each loses 0.25):
    (0.65, 0.35, 1, 0). One Newton step on the exact Hessian reaches it; the next QP step is 0."""
    from framework.optim import minimize_sqp
    a = np.array([0.9, 0.6, 1.4, -0.2])
    res = minimize_sqp(lambda x, g: (float(0.5 * np.sum((x - a) ** 2)), x - a), lambda x: np.eye(4),
                       np.full(4, 0.2), inequality_groups=[[0, 1]])
    np.testing.assert_allclose(res.x, [0.65, 0.35, 1.0, 0.0], atol=1e-12)
    assert res.status == "XTOL_REACHED" and res.n_eval == 2


def test_minimize_sqp_agrees_with_slsqp_on_a_polynomial():
    """A non-quadratic polynomial, f = Σ_i (x_i x_{i+1} - t_i)² + 0.1 Σ (x_i - 0.3)⁴ on [0, 1]⁴ with
    x0 + x1 <= 1 and x2 + x3 <= 1 (the optimum is on a constraint): SQP with its exact Hessian and
    nlopt's SLSQP end within 1e-7 of each other from the same start."""
    from framework.optim import minimize, minimize_sqp
    t = np.array([0.3, 0.05, 0.4])

    def f(x, need=True):
        r = x[:-1] * x[1:] - t
        g = np.zeros(4)
        g[:-1] += 2 * r * x[1:]
        g[1:] += 2 * r * x[:-1]
        return float(r @ r + 0.1 * np.sum((x - 0.3) ** 4)), g + 0.4 * (x - 0.3) ** 3

    def hess(x):
        r, H = x[:-1] * x[1:] - t, np.diag(1.2 * (x - 0.3) ** 2)
        for i in range(3):
            u = np.zeros(4)
            u[i], u[i + 1] = x[i + 1], x[i]
            H += 2 * np.outer(u, u)
            H[i, i + 1] += 2 * r[i]
            H[i + 1, i] += 2 * r[i]
        return H

    groups, x0 = [[0, 1], [2, 3]], np.full(4, 0.5)
    sqp = minimize_sqp(f, hess, x0, inequality_groups=groups, xtol=1e-12, ftol_rel=1e-16)
    ref = minimize(f, x0, inequality_groups=groups, xtol_rel=1e-12, ftol_rel=1e-16)
    np.testing.assert_allclose(sqp.x, ref.x, atol=1e-7)
    assert sqp.f <= ref.f + 1e-12 and sqp.x[2] + sqp.x[3] <= 1 + 1e-12


def test_minimize_sqp_keeps_its_hessian_where_even_newton_is_linear():
    """f = (x0 - 0.3)² + x1^2.5 on [0, 1]²: Newton on x^2.5 shrinks each step by 1/3 (by hand:
    x - (2.5 x^1.5) / (3.75 x^0.5) = x / 3), so a fresh Hessian per step buys nothing. The minimiser
    (0.3, 0) is reached to 1e-6 with fewer Hessians than steps (:data:`SQP_SHRINK` = 0.5 keeps it)."""
    from framework.optim import minimize_sqp
    calls = []

    def f(x, need):
        x1 = max(x[1], 0.0)
        return float((x[0] - 0.3) ** 2 + x1 ** 2.5), np.array([2 * (x[0] - 0.3), 2.5 * x1 ** 1.5])

    def hess(x):
        calls.append(1)
        return np.diag([2.0, max(3.75 * max(x[1], 0.0) ** 0.5, 1e-12)])

    res = minimize_sqp(f, hess, np.array([0.9, 0.9]), xtol=1e-9, ftol_rel=1e-16)
    np.testing.assert_allclose(res.x, [0.3, 0.0], atol=1e-6)
    assert len(calls) < res.n_eval / 2


def test_minimize_sqp_stop_keeps_last_accepted():
    """StopOptimization at the second evaluation (the first step's line search): status
    FORCED_STOP, the start (the last accepted iterate) and its cost."""
    from framework.optim import StopOptimization, minimize_sqp
    calls = []

    def f(x, need):
        if len(calls) == 1:
            raise StopOptimization
        calls.append(x.copy())
        return float(np.sum((x - 0.9) ** 2)), 2 * (x - 0.9)

    res = minimize_sqp(f, lambda x: 2 * np.eye(2), np.array([0.1, 0.1]))
    assert res.status == "FORCED_STOP" and res.n_eval == 1
    np.testing.assert_allclose(res.x, [0.1, 0.1])
    assert res.f == pytest.approx(2 * 0.8 ** 2)


def test_minimize_rejects_lbfgs_with_constraints():
    from framework.optim import minimize
    with pytest.raises(ConfigError, match="LD_LBFGS"):
        minimize(lambda x, g: (0.0, np.zeros(2)), np.zeros(2), inequality_groups=[[0, 1]], algorithm="LD_LBFGS")


def test_project_feasible():
    """Clip to [0, 1]; a segment's sum > 1 goes to the nearest point of the simplex face."""
    from framework.registry import Parameter
    from methods._common import project_feasible
    params = [Parameter(0, 0, "a", "diffuse"), Parameter(1, 0, "a", "specular"), Parameter(2, 1, "b", "diffuse")]
    rho = np.array([[0.9, 1.4], [0.5, -0.2], [1.3, 0.4]])
    out = project_feasible(rho, params)
    np.testing.assert_allclose(out, [[0.7, 1.0], [0.3, 0.0], [1.0, 0.4]])


def test_minimize_sqp_leaps_where_newton_shrinks_geometrically(monkeypatch):
    """f = (x0 - 0.3)² + x1⁴ on [0, 1]²: Newton on x⁴ shrinks each step to 2/3 of the last (by
    hand: x - 4x³ / 12x² = 2x / 3), and a kept Hessian slower still, so x1 crawls to 0. Within 80
    iterations from (0.9, 0.9): with the leaps x1 < 1e-5, without them (never three ratios in a
    row) x1 > 1e-3; x0 = 0.3 to 1e-9 in both."""
    from framework.optim import minimize_sqp, sqp

    def f(x, need):
        return float((x[0] - 0.3) ** 2 + x[1] ** 4), np.array([2 * (x[0] - 0.3), 4 * x[1] ** 3])

    def run():
        return minimize_sqp(f, lambda x: np.diag([2.0, max(12 * x[1] ** 2, 1e-300)]), np.array([0.9, 0.9]),
                            xtol=1e-12, ftol_rel=1e-16, max_iter=80)

    leaping = run()
    with monkeypatch.context() as m:
        m.setattr(sqp, "LEAP_STEPS", 10 ** 6)
        crawling = run()
    assert leaping.x[1] < 1e-5 < 1e-3 < crawling.x[1], (leaping.x, crawling.x)
    for res in (leaping, crawling):
        assert abs(res.x[0] - 0.3) < 1e-9 and res.f <= f(np.array([0.9, 0.9]), True)[0]


def test_minimize_sqp_stops_where_the_gain_is_roundoff():
    """f = 1 + Σ (x - a)⁴ with a deterministic noise of amplitude η = 10⁻¹¹ on every evaluation
    (a cost summed over many pixels has such roundoff): Newton steps shrink by 2/3 and their
    gains fall below η. The line search stops once halving a rejected step leaves its gap to
    the model as large (``ROUNDOFF_LIMITED``) instead of halving to α = 1e-12: 44 evaluations
    (99 without the rule, measured), the cost within 2η of 1 (so x within (2η)^¼ ≈ 2.2e-3 of a),
    and ``hessian`` is the Hessian at the returned point (the last step's, rejected)."""
    import hashlib

    from framework.optim import minimize_sqp
    a = np.array([0.3, 0.2, 0.7, 0.4])

    def f(x, need=True):
        h = int.from_bytes(hashlib.blake2b(x.tobytes(), digest_size=8).digest(), "little")
        return float(1.0 + np.sum((x - a) ** 4) + 1e-11 * (h / 2**64 - 0.5)), 4 * (x - a) ** 3

    def hess(x):
        return np.diag(12 * (x - a) ** 2)

    res = minimize_sqp(f, hess, np.full(4, 0.9), ftol_rel=1e-14, xtol=1e-10)
    assert res.status == "ROUNDOFF_LIMITED" and res.n_eval <= 60
    assert res.f - 1.0 <= 2e-11
    np.testing.assert_allclose(res.x, a, atol=2.2e-3)
    np.testing.assert_array_equal(res.hessian, hess(res.x))


@pytest.mark.parametrize("ftol_rel, kept", [(1e-12, True), (1e-8, False)])
def test_minimize_sqp_hands_back_the_hessian_its_last_tiny_step_started_from(ftol_rel, kept):
    """f = 1 + Σ (x - a)² + Σ (x - a)³ from 0.5: Newton steps on fresh Hessians until one gains less
    than ``ftol_rel`` (``FTOL_REACHED``). At 1e-12 that last step moves a weight 1.2e-7 (measured):
    ``hessian`` is the Hessian computed where it started, within 6 · 1.2e-7 of the one at ``x``; at
    1e-8 it moves one 1.3e-5, beyond :data:`~framework.optim.sqp.HESSIAN_REUSE_STEP`: None."""
    from framework.optim import minimize_sqp
    from framework.optim.sqp import HESSIAN_REUSE_STEP
    a = np.array([0.3, 0.2, 0.7, 0.4])
    at = []

    def f(x, need=True):
        return float(1.0 + np.sum((x - a) ** 2) + np.sum((x - a) ** 3)), 2 * (x - a) + 3 * (x - a) ** 2

    def hess(x):
        at.append(x.copy())
        return np.diag(2 + 6 * (x - a))

    res = minimize_sqp(f, hess, np.full(4, 0.5), ftol_rel=ftol_rel, xtol=1e-14)
    step = np.max(np.abs(res.x - at[-1]))
    assert res.status == "FTOL_REACHED" and step > 0.0
    assert (step <= HESSIAN_REUSE_STEP) == kept
    if kept:
        np.testing.assert_array_equal(res.hessian, np.diag(2 + 6 * (at[-1] - a)))
        np.testing.assert_allclose(res.hessian, np.diag(2 + 6 * (res.x - a)), atol=6 * step)
    else:
        assert res.hessian is None


def test_binding_step_equals_the_whole_qp():
    """``_binding_step`` on 80 weights, 20 at 0 with the gradient pushing them there, two Σ <= 1
    groups (one active): the step of the QP without the held weights equals quadprog's step on
    the whole QP to 1e-12, held weights 0; where a held weight's multiplier is negative (the
    gradient pushes it out once the others move) it declines (None) and the whole QP decides."""
    from framework.optim.feasible import group_matrix
    from framework.optim.sqp import _binding_step, _qp_step
    rng = np.random.default_rng(4)
    n = 80
    A = rng.normal(size=(n, n))
    H = A @ A.T / n + np.eye(n)
    x = rng.uniform(0.05, 0.3, n)
    x[:20] = 0.0
    x[20:22] = 0.5                                     # group {20, 21} sums to 1: active
    g = rng.normal(size=n)
    g[:20] = 5.0 + np.abs(g[:20])
    lo, hi = np.zeros(n), np.ones(n)
    M = group_matrix([np.array([20, 21]), np.array([30, 31, 32])], n)
    C = np.hstack([np.eye(n), -np.eye(n), -M.T])
    whole = _qp_step(H, g, C, np.concatenate([lo - x, x - hi, M @ x - 1.0]))
    held = _binding_step(H, g, x, lo, hi, M)
    np.testing.assert_allclose(held, whole, rtol=0, atol=1e-12)
    assert np.all(held[:20] == 0.0)
    H[0, 20:] = H[20:, 0] = -2.0                       # weight 0 now pulled off its bound
    H = H + n * np.eye(n)
    g[20:] = -50.0
    g[0] = 1e-3
    assert _binding_step(H, g, x, lo, hi, M) is None
    assert _qp_step(H, g, C, np.concatenate([lo - x, x - hi, M @ x - 1.0]))[0] > 0.0
