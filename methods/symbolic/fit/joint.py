"""The joint fit (``method.cost=joint``, the paper's eq. 6): one L2 cost over every pixel.

The observable parameters (those some pixel depends on) are solved on the pass's summed Gram
system restricted to them (optionally projected onto the PSD matrices), by
:func:`~methods.symbolic.fit.solve.solve_polynomial`; their standard errors come from the exact
Hessian (:func:`~methods.symbolic.uncertainty.standard_errors.parameter_uncertainty`), with the sandwich's meat
from each pixel's score when the per-pixel terms are given, and the registered cameras' pose
uncertainty (``method.align``) propagated into it.
"""
from __future__ import annotations

import time

import numpy as np

from framework.executor import make_executor
from framework.memory import release_freed_memory
from methods.symbolic.fit.fit import Fit, full
from methods.symbolic.fit.solve import check_solve_memory, solve_polynomial
from methods.symbolic.misfit.alignment import pose_terms
from methods.symbolic.misfit.clusters import view_clusters
from methods.symbolic.options import SymbolicOptions
from methods.symbolic.uncertainty.observability import observable_parameters, restrict_system
from methods.symbolic.uncertainty.sandwich_meat import score_meat
from methods.symbolic.uncertainty.standard_errors import correlation_extra, parameter_uncertainty


def fit_joint(system, basis, params, x0: np.ndarray, problem, options: SymbolicOptions, *, views, groups,
              defer_std: bool = False) -> Fit:
    """Solve the joint cost on the observable parameters; NaN estimate and std for the others.

    Parameters
    ----------
    system : GramSystem
        The summed system, handed over: it is released once restricted.
    basis : MonomialBasis
        Its monomials over ``params``.
    params : list of Parameter
        The parameters (ρ, then any gains of the field path).
    x0 : numpy.ndarray
        ``(P, C)`` start.
    problem : Problem
    options : SymbolicOptions
        ``psd``, ``std``, ``std_device`` and ``solver.*`` are read.
    views : callable or None
        ``views()`` gives ``(coefficients, y, weights or None)`` per view: the per-pixel terms of
        the ``sandwich`` and ``cluster`` std (None: the ``residual`` std).
    groups : list of list of int
        The parameter indices sharing a Σρ <= 1 constraint.
    defer_std : bool
        Return the estimate with ``std`` NaN and the standard errors in ``Fit.deferred_std``
        (:func:`~methods.symbolic.fit.with_std` computes them).
    """
    method = options.std if views is not None else "residual"
    P, C = len(params), problem.n_channels
    observable = observable_parameters(system, basis)
    if not observable.any():
        nan = np.full((P, C), np.nan)
        return Fit(estimate=nan, std=nan.copy(), observable=observable, evaluated_at=np.zeros((P, C)), solve=None,
                   iterates=[], correlation=correlation_extra(params, observable, None), sigma2=None,
                   std_method=method, stages_s={})
    check_solve_memory(system, basis)
    sub_system, sub_basis, columns = restrict_system(system, basis, observable)
    del system
    t_psd = time.perf_counter()
    if options.psd:
        sub_system = sub_system.psd()
    t_psd = time.perf_counter() - t_psd
    kept = np.flatnonzero(observable)
    position = {int(j): k for k, j in enumerate(kept)}
    groups = [[position[j] for j in g if j in position] for g in groups]
    solver = options.solver
    sol = solve_polynomial(sub_system, sub_basis, segments_params=[g for g in groups if g], x0=x0[kept],
                           algorithm=solver.algorithm, starts=solver.starts, max_eval=solver.max_eval,
                           xtol_rel=solver.xtol_rel, ftol_rel=solver.ftol_rel, precondition=solver.precondition,
                           seed=int(problem.seed), executor=_block_executor(problem.settings.executor))
    estimate = full(observable, sol.estimate)
    point = Fit(estimate=estimate, std=np.full_like(estimate, np.nan), observable=observable,
                evaluated_at=np.nan_to_num(estimate), solve=sol,
                iterates=[(at, full(observable, x)) for at, x in sol.iterates],
                correlation=correlation_extra(params, observable, None), sigma2=None, std_method=method,
                stages_s={"psd": t_psd, "solver": sol.solve_s}, psd_skipped=sub_system.psd_skipped)

    def with_uncertainty() -> Fit:
        t_unc = time.perf_counter()
        release_freed_memory()       # the restriction's and the solve's temporaries
        clusters, about = None, None
        if method == "cluster":
            clusters, about = view_clusters(problem, views(), basis, np.nan_to_num(estimate))
        meat = (score_meat(sub_basis, sol.estimate, views(), columns, basis.codes, clusters=clusters,
                           poses=pose_terms(problem, views()), device=options.std_device == "device")
                if method in ("sandwich", "cluster") else None)
        unc = parameter_uncertainty(sub_system, sub_basis, sol.estimate, meat=meat, hessians=sol.hessians)
        return point.replace(std=full(observable, unc.std), correlation=correlation_extra(params, observable, unc),
                             sigma2=[float(v) for v in unc.sigma2], clusters=about,
                             stages_s={**point.stages_s, "uncertainty": time.perf_counter() - t_unc})
    return point.replace(deferred_std=with_uncertainty) if defer_std else with_uncertainty()


def _block_executor(executor):
    """``executor=dask``: a function starting the executor the solve puts independent parameter
    blocks on (only when there are several); serial: None (the blocks in turn, in process)."""
    if executor.name == "serial":
        return None
    return lambda: make_executor(executor)
