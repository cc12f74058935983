"""Minimisation of the polynomial cost (paper eq. 6 with p = 2) over the kernel weights ρ.

Per channel ``c`` the cost is ``ε²_c(ρ) = μ(ρ)ᵀ G_c μ(ρ) - 2 b_cᵀ μ(ρ) + yy_c`` (see
:mod:`methods.symbolic.system.gram`), with exact gradient ``2 J(ρ)ᵀ (G_c μ - b_c)`` and Hessian
(:class:`~methods.symbolic.system.cost.ChannelCost`). Constraints: ``0 <= ρ_j <= 1`` and, per
segment, energy conservation ``Σ_{j in segment} ρ_j <= 1``. The paper used a conjugate-gradient method (GSL,
section 4.4); here SQP on the exact Hessian (default; :func:`framework.optim.minimize_sqp`, each step an
exact QP under the constraints) or one of nlopt's constrained algorithms, the latter in coordinates
where the exact Hessian is the identity: the cost of a street spans orders of magnitude of
curvature (a wall's ρ_d against a window's ρ_s), which SLSQP's BFGS otherwise learns one
evaluation at a time.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from framework.errors import ConfigError
from framework.optim import check_algorithm, minimize, minimize_sqp, project_feasible
from framework.render.checks import check_memory
from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.cost import ChannelCost
from methods.symbolic.system.gram import GramSystem
from methods.symbolic.options import SolverOptions


@dataclass
class SolveResult:
    """Outcome of :func:`solve_polynomial`.

    Attributes
    ----------
    estimate : numpy.ndarray
        ``(D, C)`` best ρ found (feasible).
    cost : numpy.ndarray
        ``(C,)`` cost ``ε²_c`` at the estimate.
    cost_history : list of float
        Total cost (sum over channels) at each evaluation: the channel being solved at the
        evaluated point, the others at their final best (already solved) or at ``x0`` (not yet).
    eval_times_s : list of float
        Seconds since the start of the solve at each evaluation.
    n_evals : int
        Number of objective evaluations, all channels and starts.
    guess_evals : int
        Evaluations of the runs started from ``x0`` (start 0 of every channel): what the initial
        guess changes (the random starts do not depend on it).
    solve_s : float
        Wall time of the whole solve.
    blocks : list of list of int
        The independent parameter blocks solved one after the other (:func:`parameter_blocks`).
    hessians : list
        Per channel the ``(D, D)`` exact Hessian at ``estimate`` where the SQP solve ended on one
        computed there, or where its last step started when that step was below
        :data:`~framework.optim.sqp.HESSIAN_REUSE_STEP` (one block holding every parameter), else
        None: the standard errors need it at that point (:func:`~methods.symbolic.uncertainty.standard_errors.parameter_uncertainty`).
    iterates : list of (float, numpy.ndarray)
        At each evaluation: its ``time.perf_counter()`` and the ``(D, C)`` estimate the solve
        would return if it stopped there (per channel the best point seen so far; channels not
        yet solved at ``x0``).
    """

    estimate: np.ndarray
    cost: np.ndarray
    cost_history: list = field(default_factory=list)
    eval_times_s: list = field(default_factory=list)
    n_evals: int = 0
    guess_evals: int = 0
    solve_s: float = 0.0
    iterates: list = field(default_factory=list)
    blocks: list = field(default_factory=list)
    hessians: list = field(default_factory=list)


def check_solve_memory(system: GramSystem, basis: MonomialBasis) -> None:
    """Raise :class:`ConfigError` before the solve allocates more than this machine has.

    Per channel the solve holds G (the pass's, handed over, and its restriction to the observable
    parameters, both while restricting; with the sparse products' temporaries budgeted at four
    copies of 16 bytes a non-zero), the monomial vectors and sparse Jacobian
    (``size × N_max``) and dense ``D × D`` Hessians (a few per channel); the sandwich standard
    errors add per view ``pixels × D`` scores.
    """
    D, N = basis.n_params, max(basis.max_degree, 1)
    need = (4 * 16 * system.nnz + 8 * 8 * basis.size * N * system.n_channels
            + 8 * 8 * D * D * system.n_channels)
    check_memory(need, f"the symbolic solve ({basis.size} monomials, {system.nnz} non-zeros in G, "
                       f"{D} parameters)", "lower render.max_bounces or estimate fewer parameters (method.kernels)")


#: ``starts=auto``: this many starts for a block of at most :data:`AUTO_STARTS_MAX_PARAMS` parameters
AUTO_STARTS = 4
#: Above this many parameters in a block, ``starts=auto`` runs the guess start only. Measured
#: (SQP, default settings): the 3 random starts ended at the guess start's minimum on urban_canyon,
#: all views (12 parameters: within 5e-8), and on street_block with 8 and 16 buildings per side
#: (124 and 228 parameters: within 1.5e-6, equal costs), where they took 55 % and 50 % of the solve.
AUTO_STARTS_MAX_PARAMS = 32


def _starts(starts, block: np.ndarray) -> int:
    if starts != "auto":
        return int(starts)
    return AUTO_STARTS if len(block) <= AUTO_STARTS_MAX_PARAMS else 1


#: ``solver.algorithm`` of the sequential quadratic programming solve (:func:`framework.optim.minimize_sqp`)
SQP = "SQP"


def _random_start(rng, D, segments_params) -> np.ndarray:
    """Uniform in the feasible set of each segment (Dirichlet(1,...,1) with a slack component)."""
    x = rng.uniform(0.0, 1.0, D)
    for ps in segments_params:
        if len(ps) > 1:
            x[ps] = rng.dirichlet(np.ones(len(ps) + 1))[:len(ps)]
    return x


def solve_polynomial(system: GramSystem, basis: MonomialBasis, *, segments_params: list[list[int]],
                     x0: np.ndarray, algorithm: str = SolverOptions.algorithm,
                     starts: int | str = SolverOptions.starts, max_eval: int = SolverOptions.max_eval,
                     xtol_rel: float = SolverOptions.xtol_rel, ftol_rel: float = SolverOptions.ftol_rel,
                     precondition: bool = SolverOptions.precondition, seed: int = 0, executor=None) -> SolveResult:
    """Minimise the cost of every channel over ρ (SQP or nlopt), one independent parameter block at a
    time (:func:`parameter_blocks`: the cost is a sum of one term per block plus a constant, so
    the blocks' minimisers together are the joint minimiser).

    Parameters
    ----------
    system : GramSystem
        Accumulated normal equations (all views).
    basis : MonomialBasis
        The basis the coefficients were computed in (``D = basis.n_params``).
    segments_params : list of list of int
        Parameter indices of each segment: constraint ``Σ_{j in segment} ρ_j <= 1``.
    x0 : numpy.ndarray
        ``(D, C)`` (or ``(D,)``) initial guess; projected onto the feasible set.
    algorithm : str
        ``SQP`` (default: :func:`framework.optim.minimize_sqp` with the exact Hessian,
        :meth:`~methods.symbolic.system.cost.ChannelCost.metric`), or an nlopt algorithm name that
        accepts inequality constraints when a segment has several parameters (``LD_SLSQP``, ``LD_CCSAQ``,
        ``LD_MMA``...; not ``LD_LBFGS``).
    starts : int or "auto"
        Number of starts per channel and block (>= 1): ``x0``, then seeded random feasible
        points. ``auto``: :data:`AUTO_STARTS` for a block of at most :data:`AUTO_STARTS_MAX_PARAMS`
        parameters, 1 for a larger one (there the random starts cost most of the solve and, where
        measured, found nothing: see :data:`AUTO_STARTS_MAX_PARAMS`).
    max_eval : int
        Evaluation limit per start.
    xtol_rel, ftol_rel : float
        nlopt's relative tolerances on the (preconditioned) coordinates and on the cost.
    precondition : bool
        Run nlopt in coordinates where the cost's Hessian is about the identity
        (:func:`framework.optim.minimize`'s ``metric``, from
        :meth:`~methods.symbolic.system.cost.ChannelCost.metric`): at ``x0`` for the first start, at its
        minimum for the others. SLSQP then needs
        about 10-30 evaluations per start instead of 50-70 (the Hessian of a street's cost
        spans orders of magnitude, which BFGS otherwise learns one evaluation at a time).
    seed : int
        Seed of the random starts.
    executor : callable, optional
        A function returning an executor (:func:`framework.executor.make_executor`, a context
        manager), called only when there are several blocks: every (channel, block) is then
        solved as its own task on it (Dask workers with ``executor=dask``), each with its random
        starts seeded by ``(seed, channel, block)``; the estimates are the blocks' minimisers as
        in the default in-process loop (which seeds one stream for all blocks in turn). The
        iterates then hold one entry per finished block.

    Returns
    -------
    SolveResult
    """
    D, C = basis.n_params, system.n_channels
    if system.n_monomials != basis.size:
        raise ConfigError(f"system has {system.n_monomials} monomials, basis {basis.size}")
    if starts != "auto" and (isinstance(starts, str) or int(starts) < 1):
        raise ConfigError(f"starts={starts}: must be an integer >= 1 or auto")
    if int(max_eval) < 1:
        raise ConfigError(f"max_eval={max_eval}: must be >= 1")
    segs = [[int(p) for p in ps] for ps in segments_params]
    for ps in segs:
        for p in ps:
            if not 0 <= p < D:
                raise ConfigError(f"segments_params: index {p} outside [0, {D - 1}]")
    if algorithm != SQP:
        check_algorithm(algorithm, constrained=any(len(ps) > 1 for ps in segs))
    x0 = np.asarray(x0, dtype=float)
    x0 = project_feasible(np.broadcast_to(x0.reshape(D, -1), (D, C)), segs)
    rng = np.random.default_rng(seed)

    t_start = time.perf_counter()
    blocks = parameter_blocks(system, basis, segs)
    used = system.used_monomials()
    whole = [ChannelCost(system, basis, c, used) for c in range(C)]
    costs = [[_BlockCost(system, basis, c, used, block, whole[c]) for block in blocks] for c in range(C)]
    trace = _Trace(x0, [whole[c](x0[:, c])[0] for c in range(C)])
    n_evals = guess_evals = 0
    hessians = [None] * C
    options = dict(algorithm=algorithm, max_eval=int(max_eval), xtol_rel=float(xtol_rel), ftol_rel=float(ftol_rel),
                   precondition=precondition)
    if executor is not None and len(blocks) > 1:
        with executor() as pool:
            n_evals, guess_evals = _solve_blocks_on(pool, costs, blocks, trace, segs, starts, seed, options)
    else:
        for c in range(C):
            for b, block in enumerate(blocks):
                f_ref = costs[c][b].value(trace.current[:, c])
                best, evals, from_guess = _solve_block(costs[c][b], trace, c, f_ref, rng, segs,
                                                       starts=_starts(starts, block), **options)
                n_evals, guess_evals = n_evals + evals, guess_evals + from_guess
                trace.settle(c, block, np.clip(best.x, 0.0, 1.0), best.f - f_ref)
                if len(block) == D and best.hessian is not None and np.array_equal(trace.current[:, c], best.x):
                    hessians[c] = best.hessian
    estimate, best_cost = trace.current, trace.channel_costs
    history, iterates = trace.history, trace.iterates
    times = [at - t_start for at, _ in iterates]    # the same clock readings as the iterates
    return SolveResult(estimate=estimate, cost=np.array(best_cost), cost_history=history, eval_times_s=times,
                       n_evals=n_evals, guess_evals=guess_evals, solve_s=time.perf_counter() - t_start,
                       iterates=iterates, blocks=[b.tolist() for b in blocks], hessians=hessians)


def _solve_blocks_on(executor, costs, blocks, trace: _Trace, segs, starts, seed: int, options: dict) -> tuple[int, int]:
    """Every (channel, block) of :func:`solve_polynomial` as a task of ``executor``; the results
    settled into ``trace`` as they arrive. Returns the evaluations, all and from the guess."""
    keys = [(c, b) for c in range(len(costs)) for b in range(len(blocks))]
    tasks = [{"cost": costs[c][b], "x": trace.current[:, c].copy(), "segs": segs,
              "starts": _starts(starts, blocks[b]), "seed": (int(seed), c, b), "options": options} for c, b in keys]
    n_evals = guess_evals = 0
    for (c, b), out in zip(keys, executor.imap(_block_task, tasks)):
        trace.record(c, blocks[b], out["x"], out["f"], out["f_ref"], improved=True)
        trace.settle(c, blocks[b], out["x"], out["f"] - out["f_ref"])
        n_evals, guess_evals = n_evals + out["evals"], guess_evals + out["from_guess"]
    return n_evals, guess_evals


def _block_task(task: dict) -> dict:
    """One channel's block, solved where the task runs (a Dask worker): :func:`_solve_block` on a
    one-channel trace of its own. Plain data in and out."""
    cost = task["cost"]
    trace = _Trace(task["x"][:, None], [0.0])
    f_ref = cost.value(task["x"])
    best, evals, from_guess = _solve_block(cost, trace, 0, f_ref, np.random.default_rng(task["seed"]), task["segs"],
                                           starts=task["starts"], **task["options"])
    return {"x": np.clip(best.x, 0.0, 1.0), "f": float(best.f), "f_ref": float(f_ref), "evals": evals,
            "from_guess": from_guess}


def parameter_blocks(system: GramSystem, basis: MonomialBasis, segments_params: list[list[int]]) -> list[np.ndarray]:
    """Independent blocks of parameters: the connected components of the graph linking the
    parameters of one used monomial, of two monomials that G couples (any channel), and of one
    segment (their Σρ <= 1 constraint). The constant monomial couples to every monomial but holds
    no parameter (it only adds linear terms), so it links nothing. The cost is then a sum of one
    term per block plus a constant, and each block can be minimised on its own, exactly.

    The graph is built on the D parameters directly (a D x D adjacency): a monomial's parameters
    are linked to each other, so two coupled monomials need only their first parameters linked.
    G's entries are looked at only while the graph has several components (a 296-weight
    street's monomials alone link every weight: its 3 x 15.5M entries took 0.7 s a fit).
    """
    D = basis.n_params
    monomials, params = basis.incidence
    keep = np.isin(monomials, system.used_monomials())
    first = np.full(basis.size, -1, dtype=np.int64)            # a parameter of each monomial
    first[monomials[keep][::-1]] = params[keep][::-1]
    adjacency = np.zeros(D * D, dtype=bool)
    adjacency[first[monomials[keep]] * D + params[keep]] = True
    for ps in segments_params:
        adjacency[ps[0] * D + np.asarray(ps[1:], dtype=np.int64)] = True
    for c in range(system.n_channels):
        if _components(adjacency, D)[0] == 1:   # before a dense system's triangle is cut
            break
        g = system.G[c].tocsr()
        for lo, hi in _row_chunks(g.indptr, PAIRS_PER_CHUNK):    # bounded temporaries
            if _components(adjacency, D)[0] == 1:
                break
            rows = np.repeat(np.arange(lo, hi), np.diff(g.indptr[lo:hi + 1]))
            a, b = first[rows], first[g.indices[g.indptr[lo]:g.indptr[hi]]]
            on = (a >= 0) & (b >= 0)
            adjacency[a[on] * D + b[on]] = True
    _, labels = _components(adjacency, D)
    return [np.flatnonzero(labels == label) for label in np.unique(labels)]


def _components(adjacency: np.ndarray, D: int) -> tuple[int, np.ndarray]:
    """Connected components of the parameters' graph (a flat ``D x D`` adjacency)."""
    return connected_components(sp.csr_matrix(adjacency.reshape(D, D)), directed=False)


#: non-zeros of G looked at together by :func:`parameter_blocks` (its temporaries: 17 bytes each)
PAIRS_PER_CHUNK = 1 << 22


def _row_chunks(indptr: np.ndarray, per_chunk: int):
    """``(lo, hi)`` row ranges of a CSR matrix holding about ``per_chunk`` non-zeros each."""
    n = len(indptr) - 1
    cuts = np.searchsorted(indptr, np.arange(0, indptr[-1], per_chunk), side="right") - 1
    edges = np.unique(np.concatenate([np.clip(cuts, 0, n), [n]]))
    if edges[0] != 0:
        edges = np.concatenate([[0], edges])
    return list(zip(edges[:-1], edges[1:]))


class _BlockCost:
    """One channel's cost restricted to one parameter block: the monomials whose parameters lie
    in the block, plus the constant one. Its value is the block's term of the cost plus a
    constant (the constant monomial's terms and yy), so differences of values are exact."""

    def __init__(self, system: GramSystem, basis: MonomialBasis, c: int, used: np.ndarray, block: np.ndarray,
                 whole: ChannelCost | None = None):
        inside = np.zeros(basis.n_params + 1, dtype=bool)
        inside[block] = True
        inside[-1] = True                          # digit 0 (empty) maps to the last entry
        in_block = inside[basis.digits - 1].all(axis=1)
        mine = used[in_block[used]]
        # ``whole``: the channel's cost over ``used``, itself when the block holds every monomial
        self.cost = whole if whole is not None and len(mine) == len(used) else ChannelCost(system, basis, c, mine)
        self.block = block

    def value(self, x: np.ndarray) -> float:
        return self.cost(x)[0]


class _Trace:
    """History and iterates of the solve, block by block: the estimate if it stopped
    now (per channel and block the best point seen so far, the rest at ``x0``) and the total
    cost there (every channel, every block)."""

    def __init__(self, x0: np.ndarray, channel_costs: list[float]):
        self.current = x0.copy()
        self.channel_costs = list(channel_costs)
        self.history, self.iterates = [], []

    def record(self, c: int, block: np.ndarray, x: np.ndarray, f: float, f_ref: float, improved: bool) -> None:
        now = time.perf_counter()
        self.history.append(sum(self.channel_costs) - f_ref + f)
        if improved:
            self.current[block, c] = np.clip(x, 0.0, 1.0)
        self.iterates.append((now, self.current.copy()))

    def settle(self, c: int, block: np.ndarray, x: np.ndarray, change: float) -> None:
        """The block's final point: the channel's total cost moves by ``change``."""
        self.current[block, c] = x
        self.channel_costs[c] += change

    def _with(self, c: int, block: np.ndarray, xb: np.ndarray) -> np.ndarray:
        x = self.current[:, c].copy()
        x[block] = xb
        return x


def _solve_block(cost: _BlockCost, trace: _Trace, c: int, f_ref: float, rng, segs, *, starts: int,
                 algorithm: str, max_eval: int, xtol_rel: float, ftol_rel: float, precondition: bool):
    """Multi-start solve (SQP or nlopt) of one block of one channel (the other blocks held where
    they are, which does not change this block's term; ``f_ref`` its value at the start).
    Returns the best run, the evaluations, and those of the start from ``x0``."""
    block = cost.block
    local = {int(p): i for i, p in enumerate(block)}
    block_segs = [[local[p] for p in ps] for ps in segs if ps[0] in local]
    best_f = np.inf

    def full(xb):
        return trace._with(c, block, xb)

    def cost_grad(xb, need_grad):
        nonlocal best_f
        f, g = cost.cost(full(xb))
        trace.record(c, block, xb, f, f_ref, improved=f < best_f)
        best_f = min(best_f, f)
        return f, g[block]

    sqp = algorithm == SQP

    def curvature_at(xb):
        """SQP: the exact Hessian (its QP convexifies it); nlopt: the preconditioning metric."""
        x = full(xb)
        return (cost.cost.hessian(x) if sqp else cost.cost.metric(x))[np.ix_(block, block)]

    x0 = trace.current[block, c].copy()
    best, evals, from_guess = None, 0, 0
    # the first start's curvature: SQP computes its own at x0, nlopt gets the metric there
    metric = curvature_at(x0) if precondition and not sqp else None
    for k in range(starts):
        start = x0 if k == 0 else _random_start(rng, len(block), block_segs)
        if (sqp or precondition) and k == 1:     # the random starts: curvature at the first minimum
            metric = curvature_at(best.x)
        if algorithm == SQP:
            run = minimize_sqp(cost_grad, curvature_at, start,
                               lower=0.0, upper=1.0, inequality_groups=block_segs, max_iter=max_eval,
                               xtol=xtol_rel, ftol_rel=ftol_rel, start_hessian=metric)
        else:
            run = minimize(cost_grad, start, lower=0.0, upper=1.0, inequality_groups=block_segs,
                           algorithm=algorithm, max_eval=max_eval, xtol_rel=xtol_rel, ftol_rel=ftol_rel,
                           constraint_tol=1e-12, metric=metric)
        evals += run.n_eval
        from_guess += run.n_eval if k == 0 else 0
        if best is None or run.f < best.f:
            best = run
    return best, evals, from_guess
