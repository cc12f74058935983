"""The options of ``method=differentiable``: defaults on the fields (its YAML is generated from them)."""
from __future__ import annotations

from dataclasses import dataclass

from framework.options import nullable, number, option
from methods._common import StartOptions


@dataclass(frozen=True)
class DifferentiableOptions(StartOptions):
    """``method.*`` of the differentiable-rendering baseline."""

    lr: float = option("Adam learning rate, in ρ units (picked by a sweep: docs/design-notes.md)",
                       number(0.0, 1.0, lo_open=True), default=0.1)
    beta1: float = option("Adam first-moment decay, in [0, 1)", number(0.0, 0.999999), default=0.9)
    beta2: float = option("Adam second-moment decay, in [0, 1)", number(0.0, 0.999999), default=0.999)
    iterations: int = option("most iterations; `budget.renders` usually stops the run first",
                             number(1, integer=True), default=1000)
    spp_grad: int | None = option("samples per pixel of the backward pass; `null`: `render.spp`",
                                  nullable(number(1, integer=True)), default=None)
