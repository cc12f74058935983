"""``method=symbolic_paper``: the paper's symbolic ray tracing as published (Coubard et al.,
sections 4.2-4.4): one polynomial pass truncated at N_max reflections, one exact solve.

A preset of :class:`methods.symbolic.SymbolicMethod` (its configuration derives from
``symbolic.yaml`` with ``tail_bounces: 0`` and ``refine: 0``): the benchmark's reproduction of the
paper's Tables 1 and 2 and its equal-budget comparisons use it; ``method=symbolic`` is the
accurate default (light beyond N_max, refinement passes until the estimate stops moving).
"""
from __future__ import annotations

from framework.registry import register
from methods.symbolic import SymbolicMethod


@register("symbolic_paper")
class SymbolicPaperMethod(SymbolicMethod):
    """:class:`~methods.symbolic.SymbolicMethod` with the paper's single truncated pass
    (``framework/conf/method/symbolic_paper.yaml``); every other option is ``symbolic``'s."""
