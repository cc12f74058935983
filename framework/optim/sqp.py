"""Sequential quadratic programming on an exact Hessian under bounds and Σ x <= 1 groups: the
``SQP`` algorithm of the symbolic solve (each step an exact dense QP from ``quadprog``)."""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from framework.optim.feasible import group_matrix, project_feasible
from framework.optim.nlopt_solver import METRIC_FLOOR
from framework.optim.result import OptimResult, StopOptimization

#: :func:`minimize_sqp` recomputes the Hessian when a step is more than this times the previous one.
#: Near a minimum where weights are flat (a weight the data barely see, sliding to 0) even a
#: fresh exact Hessian only shrinks the steps linearly; measured on a 228-weight street (its first
#: pass, 3 channels): with 0.25 every one of those steps took a new Hessian (38 in all, 41 s),
#: with 0.5 22 (22 s), the minimiser the same within 5e-6 and its cost within 1e-9 relative.
SQP_SHRINK = 0.5


def minimize_sqp(fun_and_grad: Callable[[np.ndarray, bool], tuple[float, np.ndarray | None]],
                 hessian: Callable[[np.ndarray], np.ndarray], x0: np.ndarray, *,
                 lower: float | np.ndarray = 0.0, upper: float | np.ndarray = 1.0,
                 inequality_groups: Sequence[Sequence[int]] = (), max_iter: int = 100,
                 xtol: float = 1e-10, ftol_rel: float = 1e-14, start_hessian: np.ndarray | None = None
                 ) -> OptimResult:
    """Minimise ``f`` under the constraints of :func:`minimize` by sequential quadratic
    programming with a Hessian: the algorithm ``SQP`` of the symbolic solve.

    Each iteration minimises the quadratic model ``gᵀd + ½ dᵀHd`` (``H = hessian(x)``; when it is
    not positive definite, its negative eigenvalues mirrored and all floored at
    :data:`METRIC_FLOOR` times the largest magnitude) over the feasible set, exactly (a dense
    dual active-set QP, Goldfarb and Idnani 1983, from ``quadprog``), then backtracks along the
    step until the Armijo condition holds.
    The feasible set is convex, so every iterate is feasible. With the exact Hessian near the
    minimum the steps are Newton steps: a few iterations, each one O(n³) in the parameters, where
    nlopt's SLSQP (a BFGS estimate of the Hessian, one evaluation at a time) needs tens of
    evaluations with an O(n³) subproblem each. The Hessian is the expensive part (for the
    symbolic cost a sparse product over every monomial), so one serves several steps while it
    models the cost well; it is recomputed when a step needed backtracking, when the cost's
    decrease was off the model's by more than a factor 2, or when a step is more than
    :data:`SQP_SHRINK` times the previous one (a stale Hessian converges only linearly), unless a
    fresh Hessian's step did so too: where the cost is flat or not convex (its negative curvature
    mirrored, see :func:`_convex`) even Newton steps shrink linearly, and a new Hessian a step
    bought nothing (measured on a 296-weight street's first pass: 75 steps of one channel, each
    with a new Hessian, every step 0.85 of the one before). Once :data:`LEAP_STEPS` full steps in a
    row have shrunk by the same ratio ``r``, one leap of ``1 / (1 - r)`` times the step is tried
    (:func:`_leap`).

    Parameters
    ----------
    fun_and_grad : callable
        ``fun_and_grad(x, need_grad) -> (f, grad)``; called with ``need_grad`` True.
    hessian : callable
        ``hessian(x) -> (n, n)`` symmetric curvature of ``f`` at ``x`` (exact, or Gauss-Newton).
    x0 : ndarray
        Start point; projected onto the feasible set.
    lower, upper, inequality_groups
        As in :func:`minimize`.
    max_iter : int
        Most iterations (each one QP and at least one evaluation; a Hessian when needed).
    xtol : float
        Stop when the QP step is at most this in every coordinate (``XTOL_REACHED``).
    ftol_rel : float
        Stop when an accepted step lowers ``f`` by at most this times ``|f|`` (``FTOL_REACHED``).
        The line search stops (``ROUNDOFF_LIMITED``) once halving a rejected step left its gap
        to the quadratic model as large as before: that gap is then the roundoff of ``f``
        (:func:`_noise`), not the model's error.
    start_hessian : ndarray, optional
        The curvature for the first step (e.g. the Hessian at a nearby minimum); default
        ``hessian(x0)``.

    Returns
    -------
    OptimResult
        The last iterate (the best: every accepted step lowers ``f``), its cost and the history
        of every evaluation; ``hessian``: ``hessian(x)`` at that iterate when the solve ended on a
        Hessian computed there (a stop on the step's size or gain confirms on a fresh one, and
        roundoff shows on a fresh one's step), or at the start of a last step gaining less than
        ``ftol_rel`` and moving no weight more than :data:`HESSIAN_REUSE_STEP`; else None.
    """
    x = np.asarray(x0, dtype=float).ravel()
    n = x.size
    lo = np.broadcast_to(np.asarray(lower, dtype=float), (n,)).copy()
    hi = np.broadcast_to(np.asarray(upper, dtype=float), (n,)).copy()
    groups = [np.asarray(g, dtype=int) for g in inequality_groups if len(g) > 1]
    M = group_matrix(groups, n)
    x = np.clip(project_feasible(x, groups) if groups else x, lo, hi)
    C = np.hstack([np.eye(n), -np.eye(n), -M.T])               # quadprog: Cᵀ d >= b
    res = OptimResult(x=x, f=np.inf, status="MAXEVAL_REACHED")
    f = np.inf

    def evaluate(z):
        f, g = fun_and_grad(z, True)
        res.history.append(float(f))
        res.n_eval += 1
        return float(f), np.asarray(g, dtype=float).ravel()

    H = None if start_hessian is None else np.asarray(start_hessian, dtype=float)
    H_at, H_last = None, None       # the last Hessian computed, kept when H is dropped, and its point
    convex = None if H is None else _convex(H)       # the QP's matrix: once per H, which serves several steps
    last_step = np.inf
    linear = False                  # a fresh Hessian's step shrank slowly too: shrinking is no reason
    ratios: list[float] = []        # of the steps while they shrink linearly
    try:
        f, g = evaluate(x)
        for _ in range(int(max_iter)):
            fresh = H is None
            if fresh:
                H, H_at = np.asarray(hessian(x), dtype=float), x
                H_last = H
                convex = _convex(H)
            d = _binding_step(convex, g, x, lo, hi, M) if n >= BINDING_MIN_PARAMS else None
            if d is None:
                d = _qp_step(convex, g, C, np.concatenate([lo - x, x - hi, M @ x - 1.0]))
            if np.max(np.abs(d), initial=0.0) <= xtol:
                if not fresh:                  # confirmed on a Hessian of this point before stopping
                    H, linear = None, False
                    continue
                res.status = "XTOL_REACHED"
                break
            slope, curvature = float(g @ d), float(d @ H @ d)
            leap = _leap(ratios)
            jumped = False
            if leap is not None:               # the steps' geometric sum at once (see _leap)
                z = np.clip(x + leap * d, lo, hi)
                z = np.clip(project_feasible(z, groups), lo, hi) if groups else z
                fz, gz = evaluate(z)
                jumped = fz <= f + 1e-4 * leap * min(slope, 0.0)
            alpha, miss = 1.0, None
            while not jumped:
                z = np.clip(x + alpha * d, lo, hi)
                fz, gz = evaluate(z)
                if fz <= f + 1e-4 * alpha * min(slope, 0.0) or alpha < 1e-12:
                    break
                # the model's miss shrinks 4-8 times a halving; roundoff of f does not (see _noise)
                miss, was = abs(fz - f - alpha * slope - 0.5 * alpha * alpha * curvature), miss
                if _noise(miss, was, f):
                    break
                alpha *= 0.5
            if fz > f:                         # no descent along the step: roundoff at the minimum
                res.status = "ROUNDOFF_LIMITED"
                break
            predicted, step = -(slope + 0.5 * curvature), float(np.max(np.abs(d)))
            slow = step > SQP_SHRINK * last_step
            shrinking = slow and step < last_step and alpha == 1.0 and not jumped
            ratios = ratios + [step / last_step] if shrinking else []
            if leap is not None and not jumped:
                ratios = []                    # a failed leap: the next needs a new run of ratios
            if jumped:
                H, linear = None, False        # far from where H was: a new one (and new ratios)
            elif alpha < 1.0 or not 0.5 * predicted <= f - fz <= 2.0 * predicted:
                H, linear = None, False        # the model mispredicts: a new Hessian
            elif slow and fresh and step < last_step:
                linear = True                  # even a new Hessian converges linearly here: keep it
            elif slow and not linear:
                H = None                       # steps shrink linearly on a stale Hessian: a new one
            last_step = step
            drop, (x, f, g) = f - fz, (z, fz, gz)
            if drop <= ftol_rel * max(abs(f), np.finfo(float).tiny):
                if not fresh:                  # a stale model's small steps are no minimum yet
                    H, linear = None, False
                    continue
                res.status = "FTOL_REACHED"
                break
    except StopOptimization:
        res.status = "FORCED_STOP"
    res.x, res.f = x, f
    if H_at is not None and (np.array_equal(H_at, x) or (res.status == "FTOL_REACHED"
                             and np.max(np.abs(x - H_at), initial=0.0) <= HESSIAN_REUSE_STEP)):
        res.hessian = H_last
    return res


#: :func:`minimize_sqp` returns the Hessian of the point its last step started from when that step
#: (a ``FTOL_REACHED`` stop: a Newton step on a fresh Hessian gaining nothing) moved no weight more
#: than this: the Hessian changes in first order of the step, far below the Monte Carlo spread of a
#: standard error. Measured on a 296-weight street (bench section 5's, its passes cached,
#: 2026-12-06): 6 of its 12 SQP runs stop so, after steps of 1.6e-8 to 8.9e-6; taking their
#: Hessians moved no std by more than 1.4e-5 of itself (median 3e-10) and cut the std stage from
#: 12.1 to 9.8 s
HESSIAN_REUSE_STEP = 1e-5


def _noise(miss: float, before: float | None, f: float) -> bool:
    """Whether a rejected trial step's gap to the quadratic model, ``miss``, is roundoff: it did not
    shrink to half of the previous trial's ``before`` when the step was halved, and is at most
    :data:`NOISE_REL` ``|f|``. A model's error is of second order in the step on a stale Hessian
    and of third on an exact one, so it shrinks 4-8 times a halving; the roundoff of a cost
    summed over many pixels does not shrink at all (a 296-weight street, bench section 5: ±1e-11
    at a cost of 5). The bound keeps a long step's error, where the polynomial's higher terms
    can cancel at one length and not at half of it, from passing for roundoff. Measured on that
    street (2026-12-05): without this stop 87 of its 329 evaluations and 16 of its 80 Hessians
    came after the cost was within 1e-11 of its end, halving steps whose cost changes were noise."""
    return before is not None and 0.5 * before <= miss <= NOISE_REL * abs(f)


#: :func:`_noise`: the largest gap to the model, relative to the cost, taken for roundoff (the
#: street's was 2e-12; a stop there leaves at most about 1e-10 |f| of the cost's decrease, 0.01
#: of a weight's std where the cost sums a million pixels)
NOISE_REL = 1e-10


#: :func:`minimize_sqp` leaps once the last :data:`LEAP_STEPS` step ratios agree within
#: :data:`LEAP_SPREAD` (relative) and lie below :data:`LEAP_RATIO`
LEAP_STEPS, LEAP_SPREAD, LEAP_RATIO = 3, 0.05, 0.95


def _leap(ratios: list) -> float | None:
    """How far along the QP step to leap when the steps shrink geometrically, or None.

    Where the cost is flatter than quadratic (a weight whose monomials are all of degree 2 or
    more sliding to 0: the cost ~ ρ⁴ there), Newton steps shrink by a constant ratio ``r`` (2/3
    for ρ⁴, more on a kept Hessian) and never reach the minimum; the remaining way is the
    geometric series ``d / (1 - r)``. Measured on a 296-weight street (bench section 5,
    2026-12-05): 358 QP steps in its 12 solves, 56 in a row at r = 0.87 in one; with the leaps 250,
    the solver 69 -> 60 s, the estimates within 0.003 std of those without. The leap is
    clipped to the bounds and projected onto the groups' Σ <= 1 (a weight the step takes to its
    bound stays there), tried once and kept only if it lowers the cost by the Armijo rule along
    the step (a fresh Hessian follows it); the ordinary step follows otherwise."""
    if len(ratios) < LEAP_STEPS:
        return None
    last = np.asarray(ratios[-LEAP_STEPS:])
    r = float(last.mean())
    if r >= LEAP_RATIO or np.ptp(last) > LEAP_SPREAD * r:
        return None
    return 1.0 / (1.0 - r)


def _convex(H: np.ndarray) -> np.ndarray:
    """The matrix the QP steps use: ``H`` symmetrised and, where it is not positive definite
    (a cost that is not convex there, or a G left unprojected), its negative curvature mirrored
    and flat directions floored at :data:`METRIC_FLOOR` times its largest magnitude. Once per
    Hessian: a 296-weight street's H is indefinite at every step, and each of its QPs repeated
    this eigen-decomposition and a failed QP (2026-12-05)."""
    H = 0.5 * (H + H.T)
    try:
        np.linalg.cholesky(H)
        return H
    except np.linalg.LinAlgError:
        return _floored(H)


def _floored(H: np.ndarray) -> np.ndarray:
    """The symmetric ``H`` with its eigenvalues ``λ`` replaced by ``max(|λ|, METRIC_FLOOR max|λ|)``."""
    w, V = np.linalg.eigh(H)
    top = max(float(np.abs(w).max()), np.finfo(float).tiny)
    H = (V * np.maximum(np.abs(w), METRIC_FLOOR * top)) @ V.T
    return 0.5 * (H + H.T)


def _binding_step(H: np.ndarray, g: np.ndarray, x: np.ndarray, lo: np.ndarray, hi: np.ndarray, M: np.ndarray
                  ) -> np.ndarray | None:
    """The QP step of :func:`_qp_step` (``H`` positive definite, :func:`_convex`) with the
    weights held that sit on a bound the gradient pushes them against (``x = lo``, ``g > 0`` or
    ``x = hi``, ``g < 0``), when that is the step: a smaller QP over the others, kept only if
    every held weight's KKT multiplier ``±(g + H d + Mᵀλ)_i`` is non-negative (then it is the
    unique minimiser of the whole QP); else None. quadprog's dual active set adds the active
    bounds one at a time, O(n²) each: a 296-weight street has 30-60 weights at 0 at a step."""
    import quadprog
    binding = ((x <= lo) & (g > 0.0)) | ((x >= hi) & (g < 0.0))
    if not binding.any() or binding.all():
        return None
    free = ~binding
    n, Mf = int(free.sum()), M[:, free]
    C = np.hstack([np.eye(n), -np.eye(n), -Mf.T])
    b = np.concatenate([lo[free] - x[free], x[free] - hi[free], M @ x - 1.0])
    try:
        solution = quadprog.solve_qp(H[np.ix_(free, free)], -g[free], C, b, 0)
    except ValueError:
        return None
    d = np.zeros_like(x)
    d[free] = solution[0]
    multiplier = g + H @ d + M.T @ solution[4][2 * n:]
    held = np.where(x <= lo, multiplier, -multiplier)[binding]
    return d if np.all(held >= 0.0) else None


#: :func:`minimize_sqp` tries :func:`_binding_step` from this many weights on: below, a whole QP
#: costs less than the attempt (measured 2026-12-05, one QP with a fifth of the weights held:
#: 12 weights 14 µs against 35 µs for the smaller QP and its check, 48: 86 against 81, 96: 593
#: against 233, 296: 15.7 ms against 4.4 ms)
BINDING_MIN_PARAMS = 64


def _qp_step(H: np.ndarray, g: np.ndarray, C: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``argmin_d gᵀd + ½ dᵀHd`` subject to ``Cᵀ d >= b`` (``d = 0`` feasible; ``H`` positive
    definite, :func:`_convex`)."""
    import quadprog
    try:
        return quadprog.solve_qp(H, -g, C, b, 0)[0]
    except ValueError:   # positive definite to numpy's Cholesky, not to quadprog's: floor it
        return quadprog.solve_qp(_floored(H), -g, C, b, 0)[0]

