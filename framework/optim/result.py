"""What the solvers return and raise: :class:`OptimResult`, :class:`OptimizationError`,
:class:`StopOptimization`."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


class OptimizationError(RuntimeError):
    """nlopt failed for a reason other than a normal stop; the message says which."""


class StopOptimization(Exception):
    """Raise inside the objective to stop now and keep the best point seen (e.g. budget spent)."""


@dataclass
class OptimResult:
    """Outcome of :func:`minimize`.

    ``history`` holds the cost of every objective evaluation, in order; ``status`` is nlopt's
    result name (``SUCCESS``, ``XTOL_REACHED``, ``MAXEVAL_REACHED``, ``FORCED_STOP``,
    ``ROUNDOFF_LIMITED``...).
    """

    x: np.ndarray
    f: float
    history: list[float] = field(default_factory=list)
    status: str = ""
    n_eval: int = 0
    #: the curvature the solver computed at ``x`` itself, or at the start of a last step too small to
    #: matter (SQP, :data:`~framework.optim.sqp.HESSIAN_REUSE_STEP`), else None
    hessian: np.ndarray | None = None
