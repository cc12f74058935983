"""``method=lambertian_prior``: the inversion with every segment reduced to its diffuse kernel.

The paper's Table 1 setting, and the initial guess of the kernel inversions (section 4.1:
"a preliminary inversion under a Lambertian hypothesis"; ``method.init=lambertian_prior``).
"""
from __future__ import annotations

from framework.errors import ConfigError
from framework.registry import MethodResult, register
from methods.symbolic import SymbolicMethod, prior_config


@register("lambertian_prior")
class LambertianPriorMethod(SymbolicMethod):
    """Symbolic inversion of the diffuse weights ρ_d only (specular kernels treated as absent).

    Same configuration as ``symbolic`` except ``kernels`` (always ``[diffuse]``), ``init``
    (always ``guess``: it is itself the prior) and the default ``cost: per_segment``: a
    diffuse-only model cannot reproduce mirrors and glossy segments, and the joint cost lets
    their misfit move the albedos they light (measured on urban_canyon's default view: the
    asphalt far closer per segment than joint, BENCHMARKS.md "Accurate by default";
    :mod:`methods.symbolic.fit.per_segment`).
    ``method.cost=joint`` is the paper's cost (eq. 6), which the benchmark's Table 1 uses.
    """

    kernels = ("diffuse",)

    @classmethod
    def check_options(cls, options):
        if options.init != "guess":
            raise ConfigError(f"method.init={options.init}: lambertian_prior starts from method.guess; "
                              "use method.init=guess")
        return super().check_options(options)


def lambertian_prior(problem) -> MethodResult:
    """The Lambertian prior of ``problem`` with this method's shipped options and one pass (a start
    needs no refinement): the ``prior`` that render-in-the-loop methods give
    :func:`methods._common.initial_guess`."""
    return LambertianPriorMethod(prior_config()).run(problem)
