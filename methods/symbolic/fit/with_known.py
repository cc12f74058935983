"""A fit with the scene's known weights substituted (scene.yaml ``known``: a calibration panel).

The joint or the per-segment fit runs on the free parameters only: the system, the basis and each
view's coefficients reduced by :class:`~methods.symbolic.survey.known.Substitution` (the module
:mod:`methods.symbolic.survey.known` says how), and its :class:`~methods.symbolic.fit.fit.Fit`
expanded back over every parameter, a known weight at its value with std 0.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from methods.symbolic.fit.fit import Fit
from methods.symbolic.survey.known import Substitution, known_values, room
from methods.symbolic.system.basis import MonomialBasis


def fit_with_known(solve, system, basis: MonomialBasis, params, x0: np.ndarray, problem, *, views, groups,
                   defer_std: bool = False):
    """``solve(system, basis, params, x0, problem, views=, groups=, defer_std=)`` (the joint or
    per-segment fit) on the free parameters, the known weights substituted
    (:mod:`methods.symbolic.survey.known`); the :class:`~methods.symbolic.fit.fit.Fit` it returns
    over every parameter of ``params`` (a deferred std expanded the same way when computed).
    Without known weights, ``solve`` itself."""
    values = known_values(problem.scene, params)
    if values is None:
        return solve(system, basis, params, x0, problem, views=views, groups=groups, defer_std=defer_std)
    sub = Substitution.build(basis.codes, basis.n_params, basis.max_degree, values,
                             room(problem.scene, params, values))
    known = np.isfinite(values[:, 0])
    P, C = values.shape
    if sub.n_free == 0:              # every weight known: nothing to solve
        return Fit(estimate=values.copy(), std=np.zeros((P, C)), observable=np.ones(P, bool),
                   evaluated_at=values.copy(), solve=None, iterates=[], correlation={
                       "labels": [], "matrix": [], "averaged_over_channels": True},
                   sigma2=None, std_method="known", stages_s={})
    t_known = time.perf_counter()
    if not np.array_equal(system.codes, basis.codes):
        system = system.reindexed(basis.codes)
    reduced = sub.system(system)
    del system
    t_known = time.perf_counter() - t_known
    position = {int(j): i for i, j in enumerate(sub.free)}
    free_params = [dataclasses.replace(params[j], index=i) for i, j in enumerate(sub.free)]
    free_groups = [[position[j] for j in g if j in position] for g in groups]
    mapped = None if views is None else (lambda: ((sub.view(v), y, *rest) for v, y, *rest in views()))
    fit = solve(reduced, sub.basis(), free_params, sub.reduce(x0), problem, views=mapped,
                groups=[g for g in free_groups if g], defer_std=defer_std)
    observable = known.copy()
    observable[sub.free] = fit.observable

    def expanded(fit):
        return fit.replace(estimate=sub.expand(fit.estimate), std=sub.expand(fit.std, known=0.0),
                           observable=observable, evaluated_at=sub.expand(fit.evaluated_at),
                           iterates=[(at, sub.expand(x)) for at, x in fit.iterates])
    out = expanded(fit).replace(stages_s={**fit.stages_s, "known": t_known})
    return out if fit.deferred_std is None else out.replace(deferred_std=lambda: expanded(fit.deferred_std()))
