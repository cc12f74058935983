"""The options of ``method=iterative``: defaults on the fields (``iterative.yaml`` is generated from them)."""
from __future__ import annotations

from dataclasses import dataclass

from framework.optim import ALGORITHMS
from framework.options import choice, number, option
from methods._common import StartOptions


@dataclass(frozen=True)
class IterativeOptions(StartOptions):
    """``method.*`` of the iterative baseline."""

    fd: str = option("finite differences: `forward`, D + 1 renders per gradient (D = number of parameters), "
                     "or `central`, 2D + 1; a forward step that would leave [0, 1] is taken backwards, "
                     "central steps are clipped into [0, 1]", choice("forward", "central"), default="forward")
    step: float = option("finite-difference step in ρ", number(0.0, 0.5, lo_open=True), default=0.02)
    noise: str = option("`fresh`: a new Mitsuba seed at every render (the paper); `fixed`: the same seeds "
                        "every pass (common random numbers: no noise change between the renders of a "
                        "difference, but a fixed bias)", choice("fresh", "fixed"), default="fresh")
    algorithm: str = option("nlopt algorithm; the bound-only ones (`LD_LBFGS`, `LD_TNEWTON_PRECOND_RESTART`, "
                            "`LD_VAR2`) only when every segment has one kernel (they refuse Σρ ≤ 1)",
                            choice(*ALGORITHMS), default="LD_SLSQP")
    max_eval: int = option("most cost evaluations; 0: limited by `budget.renders` only", number(0, integer=True),
            default=0)
    xtol_rel: float = option("nlopt relative tolerance on ρ", number(0.0), default=0.0001)
    ftol_rel: float = option("nlopt relative tolerance on the cost", number(0.0), default=1e-08)
