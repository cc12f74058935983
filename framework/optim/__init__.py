"""Bound- and sum-constrained minimisation of the kernel weights.

Every method that solves ``min f(x)`` subject to ``lower <= x <= upper`` and, per group of
indices ``g``, ``Σ_{i in g} x_i <= 1`` (a segment's kernel weights in one channel) goes through
one of two solvers:

* :func:`minimize` (:mod:`framework.optim.nlopt_solver`): a safe wrapper around nlopt's local
  gradient-based algorithms (the iterative baseline, and the symbolic solve's nlopt choices);
* :func:`minimize_sqp` (:mod:`framework.optim.sqp`): sequential quadratic programming on an exact
  Hessian, the symbolic solve's default.

:func:`project_feasible` (:mod:`framework.optim.feasible`) is the exact projection onto the set.
"""
from framework.optim.feasible import project_feasible
from framework.optim.nlopt_solver import (ALGORITHMS, BOUND_ONLY_ALGORITHMS, CONSTRAINED_ALGORITHMS, METRIC_FLOOR,
                                          check_algorithm, minimize)
from framework.optim.result import OptimizationError, OptimResult, StopOptimization
from framework.optim.sqp import SQP_SHRINK, minimize_sqp

__all__ = ["ALGORITHMS", "BOUND_ONLY_ALGORITHMS", "CONSTRAINED_ALGORITHMS", "METRIC_FLOOR", "SQP_SHRINK",
           "OptimResult", "OptimizationError", "StopOptimization", "check_algorithm", "minimize",
           "minimize_sqp", "project_feasible"]
