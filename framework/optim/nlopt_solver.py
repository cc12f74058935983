"""A small, safe wrapper around nlopt for bound- and sum-constrained least squares.

Every method that solves ``min f(x)`` subject to ``lower <= x <= upper`` and, per group of
indices ``g``, ``Σ_{i in g} x_i <= 1`` (a segment's kernel weights in one channel) goes
through :func:`minimize`. It works around nlopt's pitfalls (measured with nlopt 2.11):

* errors are SWIG exceptions with empty messages: they become :class:`OptimizationError`
  (or :class:`~framework.errors.ConfigError` for a bad algorithm name / option) with a message;
* roundoff-limited stops raise after the fact: the best ``x`` seen inside the objective is
  kept and returned, whatever ``optimize`` does;
* ``LD_LBFGS`` (and other unconstrained algorithms) refuse inequality constraints: this is
  checked up front and reported as a :class:`ConfigError`;
* the gradient is written in place (``grad[:] = ...``).

An objective may raise :class:`StopOptimization` (for example when a render budget is spent):
the run stops cleanly and the best point seen so far is returned.
"""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from framework.errors import ConfigError
from framework.optim.feasible import feasible, group_matrix
from framework.optim.result import OptimizationError, OptimResult, StopOptimization

#: Local gradient-based nlopt algorithms that accept nonlinear inequality constraints.
CONSTRAINED_ALGORITHMS = ("LD_SLSQP", "LD_MMA", "LD_CCSAQ")
#: Local gradient-based nlopt algorithms that take bounds only.
BOUND_ONLY_ALGORITHMS = ("LD_LBFGS", "LD_TNEWTON_PRECOND_RESTART", "LD_VAR2")
ALGORITHMS = CONSTRAINED_ALGORITHMS + BOUND_ONLY_ALGORITHMS


def check_algorithm(algorithm: str, *, constrained: bool, key: str = "algorithm") -> None:
    """Raise :class:`ConfigError` unless ``algorithm`` is usable (with constraints if needed)."""
    if algorithm not in ALGORITHMS:
        raise ConfigError(f"{key}={algorithm} is not supported: use one of {', '.join(ALGORITHMS)}")
    if constrained and algorithm not in CONSTRAINED_ALGORITHMS:
        raise ConfigError(f"{key}={algorithm} refuses the Σρ <= 1 constraints of segments with several "
                          f"kernels: use one of {', '.join(CONSTRAINED_ALGORITHMS)}")


def minimize(fun_and_grad: Callable[[np.ndarray, bool], tuple[float, np.ndarray | None]],
             x0: np.ndarray, *, lower: float | np.ndarray = 0.0, upper: float | np.ndarray = 1.0,
             inequality_groups: Sequence[Sequence[int]] = (), algorithm: str = "LD_SLSQP",
             max_eval: int = 0, xtol_rel: float = 1e-6, ftol_rel: float = 1e-10,
             constraint_tol: float = 1e-10, metric: np.ndarray | None = None) -> OptimResult:
    """Minimise ``f`` from ``x0`` under bounds and ``Σ x[g] <= 1`` for each group ``g``.

    Parameters
    ----------
    fun_and_grad : callable
        ``fun_and_grad(x, need_grad) -> (f, grad)``; ``grad`` (same shape as ``x``) is only
        read when ``need_grad`` is true. May raise :class:`StopOptimization`.
    x0 : ndarray
        Start point; clipped into the bounds (nlopt raises on an outside x0).
    lower, upper : float or ndarray
        Bounds, scalar or per coordinate.
    inequality_groups : sequence of index sequences
        Each group ``g`` adds the linear constraint ``Σ x[g] - 1 <= 0`` (groups of one index
        are implied by ``upper <= 1`` and skipped).
    algorithm : str
        nlopt algorithm name, one of :data:`ALGORITHMS` (``LD_SLSQP`` by default).
    max_eval : int
        Most objective evaluations (0: no limit).
    xtol_rel, ftol_rel : float
        nlopt's relative stopping tolerances on ``x`` and ``f``.
    constraint_tol : float
        Tolerance of each inequality constraint.
    metric : ndarray, optional
        ``(n, n)`` symmetric positive semi-definite estimate of the Hessian of ``f`` near its
        minimum (exact, or Gauss-Newton). When given, nlopt works in the coordinates ``z`` of
        ``x = x0 + P z`` with ``P = V Λ^{-1/2}`` (``metric = V Λ Vᵀ``, eigenvalues floored at
        :data:`METRIC_FLOOR` times the largest), where the Hessian is close to the identity that
        quasi-Newton methods (SLSQP's BFGS) start from: on an ill-conditioned cost this cuts the
        evaluations several-fold. The bounds become linear constraints on ``z``, and ``xtol_rel``
        applies to ``z``.

    Returns
    -------
    OptimResult
        The best feasible point seen (not necessarily nlopt's last), its cost, the history.
    """
    import nlopt
    x0 = np.asarray(x0, dtype=float).ravel()
    n = x0.size
    lo = np.broadcast_to(np.asarray(lower, dtype=float), (n,)).copy()
    hi = np.broadcast_to(np.asarray(upper, dtype=float), (n,)).copy()
    groups = [np.asarray(g, dtype=int) for g in inequality_groups if len(g) > 1]
    check_algorithm(algorithm, constrained=bool(groups))
    if metric is not None and algorithm not in CONSTRAINED_ALGORITHMS:
        raise ConfigError(f"algorithm={algorithm} with a metric: the bounds become linear constraints, "
                          f"which it refuses; use one of {', '.join(CONSTRAINED_ALGORITHMS)}")

    best = OptimResult(x=np.clip(x0, lo, hi), f=np.inf)
    stop, points = [], []
    M = group_matrix(groups, n)
    frame = _Frame(best.x, lo, hi, M, metric)

    def objective(z, grad):
        need = grad.size > 0
        x = frame.x(z)
        try:
            f, g = fun_and_grad(x, need)
        except StopOptimization:
            stop.append(True)
            raise nlopt.ForcedStop() from None
        f = float(f)
        best.history.append(f)
        points.append(x)
        best.n_eval += 1
        if need:
            grad[:] = frame.gradient(np.asarray(g, dtype=float).ravel())
        return f

    opt = nlopt.opt(getattr(nlopt, algorithm), n)
    opt.set_lower_bounds(frame.lower)
    opt.set_upper_bounds(frame.upper)
    if len(frame.A):
        opt.add_inequality_mconstraint(_linear_constraints(frame.A, frame.c),
                                       [float(constraint_tol)] * len(frame.A))
    opt.set_min_objective(objective)
    opt.set_xtol_rel(float(xtol_rel))
    opt.set_ftol_rel(float(ftol_rel))
    if max_eval > 0:
        opt.set_maxeval(int(max_eval))
    best.status = _run(opt, frame.z0.copy(), lambda: bool(stop))
    # The best feasible point seen: checked from the lowest cost up (usually the first is).
    for i in np.argsort(best.history, kind="stable"):
        if feasible(points[i], lo, hi, M, 1e-9):
            best.x, best.f = points[i], best.history[i]
            return best
    raise OptimizationError(f"nlopt {algorithm} stopped ({best.status}) before any feasible evaluation")


_STATUS = {1: "SUCCESS", 2: "STOPVAL_REACHED", 3: "FTOL_REACHED", 4: "XTOL_REACHED", 5: "MAXEVAL_REACHED",
           6: "MAXTIME_REACHED", -1: "FAILURE", -2: "INVALID_ARGS", -3: "OUT_OF_MEMORY",
           -4: "ROUNDOFF_LIMITED", -5: "FORCED_STOP"}


def _run(opt, x0: np.ndarray, stopped) -> str:
    """``opt.optimize(x0)``, turning nlopt's message-less exceptions into a status or an error.

    nlopt's Python classes (``ForcedStop``, ``RoundoffLimited``) and SWIG classes
    (``nlopt.forced_stop``, ``nlopt.runtime_error``, ``nlopt.invalid_argument``...) are not
    Python's ``RuntimeError``/``ValueError``; some algorithms (LD_LBFGS) report a forced stop
    as a bare ``runtime_error``, hence ``stopped()``.
    """
    import nlopt
    try:
        opt.optimize(x0)
    except (nlopt.ForcedStop, nlopt.forced_stop):
        return "FORCED_STOP"
    except (nlopt.RoundoffLimited, nlopt.roundoff_limited):
        return "ROUNDOFF_LIMITED"
    except nlopt.logic_error as exc:  # invalid_argument and friends
        raise OptimizationError(f"nlopt rejected its arguments ({type(exc).__name__}; check bounds, x0, "
                                "tolerances and the algorithm)") from None
    except nlopt.runtime_error:
        return "FORCED_STOP" if stopped() else "FAILURE"   # generic failure: keep the best point seen
    except MemoryError:
        raise OptimizationError("nlopt ran out of memory") from None
    return "FORCED_STOP" if stopped() else _STATUS.get(opt.last_optimize_result(), str(opt.last_optimize_result()))


def _linear_constraints(A: np.ndarray, c: np.ndarray):
    """All rows of ``A z - c <= 0`` in one nlopt vector constraint (one callback per evaluation)."""
    def constraint(result, z, grad):
        if grad.size > 0:
            grad[:] = A
        result[:] = A @ z - c
    return constraint


#: Least eigenvalue of a ``metric`` relative to its largest (flat directions get this curvature).
METRIC_FLOOR = 1e-9


class _Frame:
    """The coordinates nlopt works in: ``x`` itself, or ``z`` with ``x = x0 + P z`` (``metric``).

    Attributes: ``z0`` (start), ``lower``/``upper`` (box on the coordinates) and the linear
    constraints ``A z <= c``: the sums ``M x <= 1`` and, in ``z``, the bounds on ``x``. The box
    on ``z`` is the image of the box on ``x`` (loose, never cutting a feasible point) so that
    algorithms needing finite bounds (MMA, CCSAQ) get them.
    """

    def __init__(self, x0, lo, hi, M, metric):
        n = x0.size
        if metric is None:
            self.x0, self.P = x0, None
            self.z0, self.lower, self.upper = x0, lo, hi
            self.A, self.c = M, np.ones(len(M))
            return
        metric = np.asarray(metric, dtype=float)
        if metric.shape != (n, n) or not np.all(np.isfinite(metric)):
            raise ConfigError(f"metric must be a finite ({n}, {n}) matrix, got shape {metric.shape}")
        w, V = np.linalg.eigh(0.5 * (metric + metric.T))
        if w[-1] <= 0.0:
            raise ConfigError("metric has no positive eigenvalue: pass a positive semi-definite Hessian "
                              "estimate, or metric=None")
        w = np.maximum(w, METRIC_FLOOR * w[-1])
        self.x0, self.P = x0, V / np.sqrt(w)
        Q = np.sqrt(w)[:, None] * V.T                            # P⁻¹
        self.z0 = np.zeros(n)
        if np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)):
            ends = np.stack([Q * (lo - x0), Q * (hi - x0)])      # z_i's terms at both ends of x_j
            self.lower, self.upper = ends.min(axis=0).sum(axis=1), ends.max(axis=0).sum(axis=1)
        else:
            self.lower, self.upper = np.full(n, -np.inf), np.full(n, np.inf)
        finite_lo, finite_hi = np.isfinite(lo), np.isfinite(hi)
        self.A = np.vstack([-self.P[finite_lo], self.P[finite_hi], M @ self.P])
        self.c = np.concatenate([x0[finite_lo] - lo[finite_lo], hi[finite_hi] - x0[finite_hi],
                                 1.0 - M @ x0])

    def x(self, z: np.ndarray) -> np.ndarray:
        return np.array(z) if self.P is None else self.x0 + self.P @ z

    def gradient(self, g: np.ndarray) -> np.ndarray:
        """∇_z f from ∇_x f."""
        return g if self.P is None else self.P.T @ g
