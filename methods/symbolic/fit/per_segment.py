"""The per-segment fit (``method.cost=per_segment``): each segment's kernel weights fitted to
the pixels that see it, every other weight at its estimate.

Why
    The joint fit minimises the one cost of eq. (6) over every pixel. When the kernels cannot
    reproduce some segment (the Lambertian hypothesis of the paper's Table 1 on a street whose
    windows are mirrors), the joint minimum spends every weight on that misfit wherever the
    polynomial lets it reach, interreflections included: on urban_canyon's default view the
    asphalt's ρ_d also lights the walls, whose pixels outnumber the street's nine to one, and the
    joint Lambertian fit puts it above the truth where the asphalt's own pixels do not (measured in
    BENCHMARKS.md, section "Accurate by default").

Estimating equations
    Each parameter block ``m`` owns pixels: a segment's kernel weights the pixels whose centre
    sees the segment, a view's exposure gain (the field path) every pixel of its view. With
    ``ε²_m(ρ)`` the cost (6) over ``m``'s pixels (weighted as in the joint cost), the estimate
    solves ``U_m(ρ) = ∇_{ρ_m} ε²_m(ρ) = 0`` for every block at once, within the bounds and
    ``Σρ <= 1`` of the joint fit: each ``ρ_m`` minimises ``ε²_m`` given the others. The light a
    segment receives from the others stays the polynomial's, interreflections included (inverse
    radiosity, Yu et al. 1999, with the symbolic pixel). With a right model both fits are
    consistent; this one is less efficient (a pixel informs its own segment's weights only) and
    cannot estimate a segment no pixel sees: such a block is held at its guess and reported
    unobservable, where the joint fit may reach it through its light on the others.

Solve
    Nonlinear block Gauss-Seidel: each block in turn minimised over its own weights with the
    others fixed (SQP on the exact Hessian, :func:`framework.optim.minimize_sqp`), sweeps until
    no weight moves more than ``xtol`` (or ``max_sweeps``: reported not converged). A block's
    cost depends on the others only through interreflections, damped by albedos below 1:
    measured, 7-17 sweeps to 1e-8 on urban_canyon's Lambertian default view.

Standard errors
    The sandwich of estimating equations, ``Cov_c = J_c⁻¹ M_c J_c⁻ᵀ``: row block ``m`` of
    ``J_c = ∂U/∂ρ`` is block ``m``'s rows of the Hessian of ``ε²_m`` (``J`` is not symmetric),
    and ``M_c`` the covariance of ``U`` from each pixel's score restricted to the parameters
    owning the pixel (:func:`~methods.symbolic.uncertainty.sandwich_meat.score_meat` with ``owned``; image and
    Monte Carlo noise, and the registered cameras' pose, as for the joint fit).
"""
from __future__ import annotations

import logging
import time

import numpy as np
import scipy.sparse as sp

from framework.optim import minimize_sqp, project_feasible
from framework.render.checks import check_memory
from methods.symbolic.fit.fit import Fit
from methods.symbolic.fit.solve import SolveResult
from methods.symbolic.misfit.alignment import pose_terms
from methods.symbolic.survey.exposure import GAIN_PREFIX
from methods.symbolic.survey.vignetting import VIGNETTING_PREFIX, lens_key
from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.cost import ChannelCost
from methods.symbolic.system.view_systems import owned_systems, summed
from methods.symbolic.uncertainty.observability import observable_parameters
from methods.symbolic.uncertainty.sandwich_meat import score_meat
from methods.symbolic.uncertainty.standard_errors import correlation_extra, estimating_uncertainty

log = logging.getLogger(__name__)

#: sweeps of the block Gauss-Seidel before it is reported not converged
MAX_SWEEPS = 200


def ownership(problem, params) -> list[sp.csr_matrix]:
    """Per view (``problem.cameras`` order) the ``(pixels, D)`` 0/1 matrix: pixel ``p`` is owned
    by parameter ``j`` (its segment is seen through the pixel's centre, or ``j`` is the gain of
    the pixel's view or a vignetting coefficient of its lens)."""
    from framework.render.mitsuba_scene import segment_maps
    maps = segment_maps(problem.scene, problem.cameras)
    out = []
    for cam in problem.cameras:
        seen = maps[cam.name].ravel()
        columns = [seen == p.segment if p.segment >= 0 else
                   np.full(seen.shape, p.segment_name in (GAIN_PREFIX + cam.name, VIGNETTING_PREFIX + lens_key(cam)))
                   for p in params]
        out.append(sp.csr_matrix(np.stack(columns, axis=1).astype(np.float64)))
    return out


def parameter_blocks(params, groups: list[list[int]]) -> list[list[int]]:
    """The blocks of the fit: the ``groups`` (a segment's kernels), then the parameters in none
    of them by ``segment_name`` (a view's gain alone, a lens's three vignetting coefficients
    together: solved one at a time, these strongly correlated coefficients took the 200 sweeps)."""
    grouped = {j for g in groups for j in g}
    rest: dict[str, list[int]] = {}
    for j in range(len(params)):
        if j not in grouped:
            rest.setdefault(params[j].segment_name, []).append(j)
    return [list(g) for g in groups if g] + list(rest.values())


def block_systems(views, owned: list[sp.csr_matrix], blocks: list[list[int]]) -> list:
    """Per block the Gram system of its pixels over every view (None where it owns none); a
    view's blocks from one pass over its coefficients
    (:func:`~methods.symbolic.system.view_systems.owned_systems`)."""
    systems: list = [None] * len(blocks)
    for (coeffs, y, *weights), own in zip(views, owned):
        mask = own[:, [b[0] for b in blocks]].toarray() > 0      # a block's kernels own the same pixels
        for k, part in enumerate(owned_systems(coeffs, y, weights[0] if weights else None, mask)):
            if part is not None:
                systems[k] = summed(systems[k], part)
    return systems


def check_block_memory(system, basis: MonomialBasis, n_blocks: int) -> None:
    """Raise ConfigError before the block systems are formed when they could exceed this
    machine's memory: each holds at most the pass system's non-zeros (its pixels' monomial pairs
    are the pass's), so ``n_blocks`` times them, 16 bytes each with temporaries twice that."""
    need = 2 * 16 * n_blocks * system.nnz + 8 * 8 * basis.n_params ** 2 * system.n_channels
    check_memory(need, f"the per-segment fit ({n_blocks} blocks of up to {system.nnz} non-zeros each)",
                 "use method.cost=joint")


def solve_blocks(systems: list, basis: MonomialBasis, blocks: list[list[int]], x0: np.ndarray,
                 free: np.ndarray, groups: list[list[int]], *, xtol: float, max_sweeps: int = MAX_SWEEPS,
                 max_iter: int = 100) -> tuple[SolveResult, list[int], bool]:
    """The block Gauss-Seidel of the module docstring, per channel.

    Parameters
    ----------
    systems : list
        Per block its Gram system (:func:`block_systems`) or None.
    basis : MonomialBasis
        The monomials of the systems (``D`` parameters).
    blocks : list of list of int
        Parameter indices of each block.
    x0 : numpy.ndarray
        ``(D, C)`` start; the parameters not ``free`` keep it.
    free : numpy.ndarray
        ``(D,)`` bool: the parameters estimated (their block's pixels depend on them).
    groups : list of list of int
        Indices sharing a ``Σρ <= 1`` constraint (a segment's kernels).
    xtol : float
        Stop when no weight moved more than this in a sweep.

    Returns
    -------
    (SolveResult, list of int, bool)
        The result (``cost``: per channel the sum of the blocks' costs), the sweeps per channel,
        and whether every channel converged.
    """
    t0 = time.perf_counter()
    x = project_feasible(np.array(x0, dtype=float), groups)
    D, C = x.shape
    constrained = {tuple(sorted(g)) for g in groups if len(g) > 1}
    sweeps, converged, history, iterates, n_evals = [], True, [], [(t0, x.copy())], 0
    for c in range(C):
        costs = [None if s is None else ChannelCost(s, basis, c) for s in systems]
        for sweep in range(1, max_sweeps + 1):
            moved = 0.0
            for block, cost in zip(blocks, costs):
                idx = np.array([j for j in block if free[j]], dtype=int)
                if cost is None or not len(idx):
                    continue
                res = _minimise_block(cost, x[:, c], idx, tuple(sorted(block)) in constrained, max_iter, xtol)
                n_evals += res.n_eval
                moved = max(moved, float(np.max(np.abs(res.x - x[idx, c]))))
                x[idx, c] = res.x
            history.append(sum(cost(x[:, c])[0] for cost in costs if cost is not None))
            iterates.append((time.perf_counter(), x.copy()))
            if moved <= xtol:
                break
        else:
            converged = False
        sweeps.append(sweep)
    cost = np.array([sum(ChannelCost(s, basis, c)(x[:, c])[0] for s in systems if s is not None) for c in range(C)])
    result = SolveResult(estimate=x, cost=cost, cost_history=history,
                         eval_times_s=[at - t0 for at, _ in iterates[1:]], n_evals=n_evals,
                         solve_s=time.perf_counter() - t0, iterates=iterates, blocks=[list(b) for b in blocks])
    return result, sweeps, converged


def _minimise_block(cost: ChannelCost, x: np.ndarray, idx: np.ndarray, constrained: bool, max_iter: int,
                    xtol: float):
    """``cost`` minimised over ``x[idx]``, the other weights fixed (SQP, bounds [0, 1] and, for a
    segment's kernels, their sum <= 1)."""
    def with_block(z):
        full = x.copy()
        full[idx] = z
        return full

    def fun_and_grad(z, need_grad):
        f, g = cost(with_block(z))
        return f, g[idx]

    return minimize_sqp(fun_and_grad, lambda z: cost.metric(with_block(z))[np.ix_(idx, idx)], x[idx],
                        inequality_groups=[list(range(len(idx)))] if constrained else (),
                        max_iter=max_iter, xtol=0.1 * xtol)


def estimating_jacobian(systems: list, basis: MonomialBasis, blocks: list[list[int]], rho: np.ndarray
                        ) -> np.ndarray:
    """``(C, D, D)`` ``J_c = ∂U/∂ρ`` at ``rho`` (``(D, C)``): block ``m``'s rows of the exact
    Hessian of its own cost; rows of blocks without pixels are 0."""
    D, C = rho.shape
    J = np.zeros((C, D, D))
    for block, system in zip(blocks, systems):
        if system is None:
            continue
        for c in range(C):
            J[c, block] = ChannelCost(system, basis, c).hessian(rho[:, c])[block]
    return J


def fit_per_segment(system, basis: MonomialBasis, params, x0: np.ndarray, problem, *, views, groups,
                    xtol: float, psd: bool = True, std_device: bool = False) -> Fit:
    """The per-segment fit of one pass: a :class:`~methods.symbolic.fit.fit.Fit` whose
    ``evaluated_at`` holds the guess where a block is held and whose ``per_segment`` says the
    sweeps, whether they converged and the held parameters.

    ``system``: the pass's summed system (its size bounds the blocks'); ``views``: a function
    giving ``(coefficients, y, weights or None)`` per view in ``problem.cameras`` order;
    ``psd``: each block's system projected onto the PSD matrices (:meth:`GramSystem.psd`);
    ``std_device``: the scores' products on the run's device (:func:`~methods.symbolic.uncertainty.sandwich_meat.score_meat`).
    """
    D, C = basis.n_params, problem.n_channels
    blocks = parameter_blocks(params, groups)
    check_block_memory(system, basis, len(blocks))
    del system
    owned = ownership(problem, params)
    # over the basis's monomials, as ChannelCost reads them
    systems = [None if s is None else s.reindexed(basis.codes) for s in block_systems(views(), owned, blocks)]
    t_psd = time.perf_counter()
    if psd:
        systems = [None if s is None else s.psd() for s in systems]
    t_psd = time.perf_counter() - t_psd
    free = np.zeros(D, bool)
    for block, s in zip(blocks, systems):
        if s is not None:
            free[block] = observable_parameters(s, basis)[block]
    x0 = np.broadcast_to(np.asarray(x0, float).reshape(D, -1), (D, C))
    sol, sweeps, converged = solve_blocks(systems, basis, blocks, x0, free, groups, xtol=xtol)
    if not converged:
        log.warning("per-segment fit: a channel still moved more than %g after %d sweeps (results.json "
                    "per_segment.converged false); method.cost=joint solves the joint cost exactly", xtol, MAX_SWEEPS)
    at = sol.estimate
    t_unc = time.perf_counter()
    meat = score_meat(basis, at, views(), np.arange(basis.size), basis.codes, owned=owned,
                      poses=pose_terms(problem, views()), device=std_device)
    bread = estimating_jacobian(systems, basis, blocks, at)
    sigma2 = _residual_variance([s for b, s in zip(blocks, systems) if s is not None and params[b[0]].segment >= 0],
                                basis, at, int(free.sum()))
    keep = np.flatnonzero(free)
    unc = estimating_uncertainty(bread[:, keep][:, :, keep], meat[:, keep][:, :, keep], sigma2)
    estimate, std = np.full((D, C), np.nan), np.full((D, C), np.nan)
    estimate[keep], std[keep] = at[keep], unc.std
    held = [f"{p.segment_name}/{p.kernel}" for p, f in zip(params, free) if not f]
    return Fit(estimate=estimate, std=std, observable=free, evaluated_at=at, solve=sol,
               iterates=[(t, np.where(free[:, None], x, np.nan)) for t, x in sol.iterates],
               correlation=correlation_extra(params, free, unc), sigma2=[float(v) for v in sigma2],
               std_method="sandwich",
               stages_s={"psd": t_psd, "solver": sol.solve_s, "uncertainty": time.perf_counter() - t_unc},
               psd_skipped=tuple(n for s in systems if s is not None for n in s.psd_skipped),
               per_segment={"sweeps": sweeps, "converged": converged, "held_at_guess": held})


def _residual_variance(systems: list, basis: MonomialBasis, rho: np.ndarray, n_free: int) -> np.ndarray:
    """``(C,)`` residual variance over the segments' pixels (each once): their costs' sum at
    ``rho`` over the pixels less the estimated parameters."""
    C = rho.shape[1]
    if not systems:
        return np.zeros(C)
    mu = np.stack([basis.evaluate(rho[:, c]) for c in range(C)])
    cost = sum(s.cost(mu) for s in systems)
    return np.maximum(cost, 0.0) / max(sum(s.n_pixels for s in systems) - n_free, 1)
