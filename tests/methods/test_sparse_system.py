"""The system over the monomials that occur: the code basis, the sparse Gram and its limits."""
from itertools import combinations_with_replacement

import numpy as np
import pytest

from factory import run_street_cli
from framework.errors import ConfigError
from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.trace.monomial_codes import check_key_range
import scipy.sparse as sp

from methods.symbolic.fit.solve import check_solve_memory, solve_polynomial
from methods.symbolic.system.cost import ChannelCost
from methods.symbolic.system.gram import GramSystem
from methods.symbolic.system.upper_triangle import principal, sandwich, symmetric_dot


def _exponents(D: int, N: int) -> list[tuple[int, ...]]:
    """All exponent vectors of degree <= N, built by hand."""
    out = []
    for d in range(N + 1):
        for combo in combinations_with_replacement(range(D), d):
            out.append(tuple(np.bincount(np.array(combo, int), minlength=D)))
    return out


def _subset(D: int, N: int, keep: np.ndarray) -> tuple[MonomialBasis, np.ndarray]:
    """The basis of the monomials ``keep`` (indices into the full basis), and its exponents."""
    full = MonomialBasis(D, N)
    codes = full.codes[keep]
    return MonomialBasis(D, N, codes), full.exponents[np.union1d([0], keep)]


def test_code_basis_equals_full_basis_restricted():
    """Values, Jacobian and Hessian of an occurring-code basis equal the hand-built monomials'
    (products of powers, their derivatives by the power rule), to 1e-12."""
    D, N = 5, 3
    full = MonomialBasis(D, N)
    assert sorted(map(tuple, full.exponents)) == sorted(_exponents(D, N))
    keep = np.random.default_rng(0).choice(full.size, 20, replace=False)
    basis, E = _subset(D, N, keep)
    assert basis.size == len(np.union1d([0], keep)) and basis.codes[0] == 0
    rho = np.random.default_rng(1).uniform(0.1, 0.9, D)
    np.testing.assert_allclose(basis.evaluate(rho), np.prod(rho ** E, axis=1), rtol=1e-12)
    J = np.array([[e[k] * np.prod(rho ** (e - np.eye(D, dtype=int)[k])) if e[k] else 0.0
                   for k in range(D)] for e in E])
    np.testing.assert_allclose(basis.jacobian(rho), J, rtol=1e-12, atol=1e-15)
    r = np.random.default_rng(2).normal(size=basis.size)
    np.testing.assert_allclose(basis.jacobian_t_dot(rho, r), J.T @ r, rtol=1e-12)
    H = basis.hessian(rho)
    for m, e in enumerate(E):
        for k in range(D):
            for l in range(D):
                lowered = e - np.eye(D, dtype=int)[k] - np.eye(D, dtype=int)[l]
                coef = e[k] * (e[l] - (k == l))
                want = coef * np.prod(rho ** np.maximum(lowered, 0)) if coef > 0 else 0.0
                assert abs(H[m, k, l] - want) < 1e-12
    np.testing.assert_allclose(basis.hessian_dot(rho, r), np.einsum("m,mkl->kl", r, H), atol=1e-12)


def _system(rng, basis, n=200, C=2):
    """Random sparse coefficients over ``basis`` and pixels from a known ρ."""
    gamma = rng.uniform(0, 1, (n, basis.size, C)) * (rng.uniform(size=(n, basis.size, C)) < 0.3)
    rho = rng.uniform(0.1, 0.6, basis.n_params)
    y = np.einsum("nmc,m->nc", gamma, basis.evaluate(rho))
    return GramSystem.zeros(basis.codes, C).accumulate(gamma, y), gamma, y


def test_sparse_and_dense_give_the_same_cost_gradient_and_minimiser():
    """Sparse G vs a dense numpy reference from the same coefficients: cost and gradient to
    1e-10 relative, and the minimiser of the dense cost (scipy L-BFGS-B) within 1e-5."""
    from scipy.optimize import minimize
    rng = np.random.default_rng(3)
    basis, _ = _subset(4, 2, np.arange(1, 12))
    system, gamma, y = _system(rng, basis)
    for c in range(2):
        Gd = gamma[:, :, c].T @ gamma[:, :, c]
        bd = gamma[:, :, c].T @ y[:, c]

        def dense(x):
            mu = basis.evaluate(x)
            return mu @ Gd @ mu - 2 * bd @ mu + y[:, c] @ y[:, c], 2 * basis.jacobian(x).T @ (Gd @ mu - bd)

        x = rng.uniform(0, 1, 4)
        f, g = ChannelCost(system, basis, c)(x)
        fd, gd = dense(x)
        np.testing.assert_allclose(f, fd, rtol=1e-10)
        np.testing.assert_allclose(g, gd, rtol=1e-10)
        ref = minimize(dense, np.full(4, 0.5), jac=True, bounds=[(0, 1)] * 4, method="L-BFGS-B",
                       options={"ftol": 1e-15, "gtol": 1e-12}).x
        sol = solve_polynomial(system, basis, segments_params=[], x0=np.full(4, 0.5), starts=2)
        np.testing.assert_allclose(sol.estimate[:, c], ref, atol=1e-5)


@pytest.mark.parametrize("bound, per_entry", [(0, 10**6), (10**6, 0), (10**6, 10**6)])
def test_gauss_newton_from_the_triangle_or_dense_is_jt_g_j(monkeypatch, bound, per_entry):
    """The Gauss-Newton matrix ``2 Jᵀ G J``, the cost and its gradient from G's sparse triangle
    (above the dense bound on the monomials, or too sparse for it) and from its dense copy
    (otherwise): the dense numpy references ``2 Jᵀ (ΓᵀΓ) J`` to 1e-12 relative, the cost and
    gradient to 1e-10 (as the sparse ones in the test above)."""
    from methods.symbolic.system import cost as cost_module
    monkeypatch.setattr(cost_module, "DENSE_HESSIAN_MONOMIALS", bound)
    monkeypatch.setattr(cost_module, "DENSE_HESSIAN_FLOPS_PER_ENTRY", per_entry)
    rng = np.random.default_rng(5)
    basis, _ = _subset(4, 2, np.arange(1, 12))
    system, gamma, _ = _system(rng, basis)
    x = rng.uniform(0, 1, 4)
    for c in range(2):
        J = basis.jacobian(x)
        expected = 2.0 * J.T @ (gamma[:, :, c].T @ gamma[:, :, c]) @ J
        cost = ChannelCost(system, basis, c)
        Gd, mu = gamma[:, :, c].T @ gamma[:, :, c], basis.evaluate(x)
        bd = system.b[c]
        f, g = cost(x)
        np.testing.assert_allclose(f, mu @ Gd @ mu - 2 * bd @ mu + system.yy[c], rtol=1e-10)
        np.testing.assert_allclose(g, 2 * J.T @ (Gd @ mu - bd), rtol=1e-10)
        np.testing.assert_allclose(cost.gauss_newton(x), expected, rtol=0, atol=1e-12 * np.abs(expected).max())
        assert (cost._dense is not None) == (bound > 0 and per_entry > 0)


def test_systems_over_different_codes_add_by_merging():
    """Two views over different monomials: their sum is over the union and equals the system of
    all pixels accumulated over the union (1e-12)."""
    rng = np.random.default_rng(4)
    full = MonomialBasis(3, 2)
    a, b = np.array([0, 1, 4, 7]), np.array([0, 2, 4, 9])
    union = np.union1d(a, b)
    ga, gb = rng.uniform(size=(30, 4, 1)), rng.uniform(size=(40, 4, 1))
    ya, yb = rng.uniform(size=(30, 1)), rng.uniform(size=(40, 1))
    summed = (GramSystem.zeros(full.codes[a], 1).accumulate(ga, ya)
              + GramSystem.zeros(full.codes[b], 1).accumulate(gb, yb))
    gamma = np.zeros((70, len(union), 1))
    gamma[:30, np.searchsorted(union, a)] = ga
    gamma[30:, np.searchsorted(union, b)] = gb
    ref = GramSystem.zeros(full.codes[union], 1).accumulate(gamma, np.concatenate([ya, yb]))
    np.testing.assert_array_equal(summed.codes, ref.codes)
    np.testing.assert_allclose(summed.G[0].toarray(), ref.G[0].toarray(), rtol=1e-12)
    np.testing.assert_allclose(summed.b, ref.b, rtol=1e-12)


def test_psd_per_component_equals_dense_projection_and_skips_large_ones():
    """Projection component by component = the dense eigen projection of the whole G (1e-10);
    with a limit below a component's size that component is left as is and reported."""
    rng = np.random.default_rng(5)
    blocks = [rng.normal(size=(k, k)) for k in (3, 4)]
    dense = np.zeros((8, 8))
    dense[:3, :3] = blocks[0] + blocks[0].T
    dense[4:8, 4:8] = blocks[1] + blocks[1].T
    system = GramSystem([dense], np.zeros((1, 8)), np.zeros(1))
    w, V = np.linalg.eigh(dense)
    np.testing.assert_allclose(system.psd().matrix(0).toarray(), (V * np.maximum(w, 0)) @ V.T, atol=1e-10)
    partial = system.psd(limit=3)
    assert partial.psd_skipped == (4,)
    np.testing.assert_allclose(partial.matrix(0).toarray()[4:, 4:], dense[4:, 4:])


def test_one_triangle_stored_and_its_products_equal_the_whole_matrix():
    """G is stored as its upper triangle; the products the solve takes from it (``G x``,
    ``Jᵀ G J``, the cost, a principal submatrix) equal numpy's on the whole dense matrix (1e-12),
    and a triangle given to the constructor is kept as it is."""
    rng = np.random.default_rng(11)
    gamma = rng.normal(size=(40, 9)) * (rng.uniform(size=(40, 9)) < 0.4)
    dense = gamma.T @ gamma
    system = GramSystem([dense], rng.normal(size=(1, 9)), np.ones(1))
    stored = system.G[0]
    assert stored.nnz == np.count_nonzero(np.triu(dense))
    np.testing.assert_allclose(system.matrix(0).toarray(), dense, rtol=1e-12)
    again = GramSystem([stored], system.b, system.yy)
    assert again.G[0] is stored or np.array_equal(again.G[0].toarray(), stored.toarray())
    x = rng.normal(size=9)
    np.testing.assert_allclose(symmetric_dot(stored, x), dense @ x, rtol=1e-12)
    J = sp.csr_matrix(rng.normal(size=(9, 4)) * (rng.uniform(size=(9, 4)) < 0.5))
    np.testing.assert_allclose(sandwich(stored, J).toarray(), J.toarray().T @ dense @ J.toarray(), rtol=1e-12, atol=1e-12)
    cost = x @ dense @ x - 2 * system.b[0] @ x + 1.0
    np.testing.assert_allclose(system.cost(x[None]), [cost], rtol=1e-12)
    idx = np.array([1, 4, 5, 8])
    np.testing.assert_allclose(GramSystem([principal(stored, idx)], np.zeros((1, 4)), np.ones(1)).matrix(0).toarray(),
                               dense[np.ix_(idx, idx)], rtol=1e-12)


@pytest.mark.parametrize("rows", [2, 3, 9, 40])
def test_sandwich_is_the_same_on_one_thread_and_on_several(monkeypatch, rows):
    """``Jᵀ G J`` and ``G x`` are summed over a fixed number of row parts of G's triangle, so the
    result is bit-for-bit the same whatever the thread count (1 core, 2 cores), equals numpy's
    on the dense matrix (1e-12), also with fewer rows than parts and with empty rows."""
    import framework.threads as threads
    rng = np.random.default_rng(rows)
    gamma = rng.normal(size=(3 * rows, rows)) * (rng.uniform(size=(3 * rows, rows)) < 0.4)
    gamma[:, rows // 2] = 0.0                        # an empty row and column
    dense = gamma.T @ gamma
    stored = GramSystem([dense], np.zeros((1, rows)), np.ones(1)).G[0]
    J = sp.csr_matrix(rng.normal(size=(rows, 5)) * (rng.uniform(size=(rows, 5)) < 0.5))
    x = rng.normal(size=rows)
    out = {}
    for cores in (1, 2):
        monkeypatch.setattr(threads, "cores", lambda cores=cores: cores)
        out[cores] = sandwich(stored, J).toarray(), symmetric_dot(stored, x)
    assert np.array_equal(out[1][0], out[2][0]) and np.array_equal(out[1][1], out[2][1])
    np.testing.assert_allclose(out[2][0], J.toarray().T @ dense @ J.toarray(), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(out[2][1], dense @ x, rtol=1e-12, atol=1e-12)


def test_run_threads_keeps_the_tasks_order(monkeypatch):
    import framework.threads as threads
    monkeypatch.setattr(threads, "cores", lambda: 2)
    assert threads.run_threads([lambda i=i: i * i for i in range(7)]) == [i * i for i in range(7)]


def test_principal_errors():
    with pytest.raises(ValueError, match="increasing"):
        principal(sp.eye(4, format="csr"), np.array([2, 1]))


def test_too_large_problems_fail_with_one_line(monkeypatch):
    """Keys beyond 32 bits, and a solve above the available memory: one ConfigError line naming
    the setting to change."""
    with pytest.raises(ConfigError, match="render.max_bounces") as err:
        check_key_range(68, 6)
    assert "\n" not in str(err.value)
    import methods.symbolic.fit.solve as solve
    monkeypatch.setattr(solve, "check_memory", _tight_memory)
    basis = MonomialBasis(3, 2)
    with pytest.raises(ConfigError, match="render.max_bounces") as err:
        check_solve_memory(GramSystem.zeros(basis.codes, 3), basis)
    assert "\n" not in str(err.value)


def _tight_memory(need, what, fix):
    """:func:`framework.render.checks.check_memory` on a machine with 1 KiB available."""
    from framework.render import checks
    original = checks.available_memory_bytes
    checks.available_memory_bytes = lambda: 1024
    try:
        checks.check_memory(need, what, fix)
    finally:
        checks.available_memory_bytes = original


@pytest.mark.slow
def test_symbolic_run_on_18_materials_at_three_bounces(tmp_path):
    """K = 2 street (18 materials, D = 36) at N_max = 3, 32 x 32, 4 spp: the full basis would have
    C(39, 3) = 9139 monomials (a dense G of 3 x 9139² floats); the occurring ones run in seconds.
    The paper's single pass: this is about the monomials that occur (the default's 4 passes each
    PSD-project this tiny view's components of up to 4,000 monomials densely: 150 s measured)."""
    from scenes import street_block as sb
    folder = sb.build(tmp_path / "street2", buildings=2, image=32)
    results = run_street_cli(tmp_path, folder, "render.max_bounces=3", method="symbolic_paper")
    assert len(results["parameters"]) == 36
    assert results["n_monomials"] < 9139 and results["gram_nnz"] > 0
    assert all(0.0 <= x <= 1.0 for p in results["parameters"] for x in p["estimate"] if x is not None)


def _two_block_system(rng, n=300, C=2):
    """D = 4 weights in two segments {0, 1} and {2, 3} that no pixel mixes (a pixel's
    coefficients sit on the constant monomial and the monomials of one segment only), the
    pixels rendered at a known ρ plus noise. Returns the basis, the system and that ρ."""
    full = MonomialBasis(4, 2)
    E = full.exponents
    groups = [np.flatnonzero(E[:, 2:].sum(1) == 0), np.flatnonzero(E[:, :2].sum(1) == 0)]
    basis = MonomialBasis(4, 2, full.codes)
    gamma = np.zeros((n, basis.size, C))
    for i in range(n):
        cols = groups[i % 2]
        gamma[i][cols] = rng.uniform(0, 1, (len(cols), C)) * (rng.uniform(size=(len(cols), C)) < 0.6)
    rho = np.array([0.5, 0.2, 0.3, 0.4])
    y = np.einsum("nmc,m->nc", gamma, basis.evaluate(rho)) + rng.normal(0, 1e-3, (n, C))
    return basis, GramSystem.zeros(basis.codes, C).accumulate(gamma, y), rho


def test_independent_blocks_give_the_joint_minimiser(monkeypatch):
    """The cost splits into one term per segment here: the solve finds two blocks, and their
    separate minimisers equal the joint solve's (blocks forced into one) to 1e-6."""
    import methods.symbolic.fit.solve as S
    basis, system, rho = _two_block_system(np.random.default_rng(3))
    segs = [[0, 1], [2, 3]]
    assert [b.tolist() for b in S.parameter_blocks(system, basis, segs)] == [[0, 1], [2, 3]]
    split = solve_polynomial(system, basis, segments_params=segs, x0=np.full(4, 0.5), starts=2)
    assert split.blocks == [[0, 1], [2, 3]]
    monkeypatch.setattr(S, "parameter_blocks", lambda *a: [np.arange(4)])
    joint = solve_polynomial(system, basis, segments_params=segs, x0=np.full(4, 0.5), starts=2)
    np.testing.assert_allclose(split.estimate, joint.estimate, atol=1e-6)
    np.testing.assert_allclose(split.cost, joint.cost, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(split.estimate[:, 0], rho, atol=0.02)
    # the cost recorded at the last evaluation is the total over channels and blocks
    assert split.cost_history[-1] >= split.cost.sum() - 1e-9


def test_a_segment_constraint_joins_its_weights():
    """Two weights of one segment are one block even if no monomial holds both."""
    import methods.symbolic.fit.solve as S
    basis, system, _ = _two_block_system(np.random.default_rng(4))
    assert [b.tolist() for b in S.parameter_blocks(system, basis, [[0, 1, 2, 3]])] == [[0, 1, 2, 3]]


@pytest.mark.slow
@pytest.mark.parametrize("where", ["serial", "dask"])
def test_blocks_as_executor_tasks_give_the_same_minimiser(where):
    """Each (channel, block) solved as a task of an executor (in process, or on 2 Dask workers)
    gives the in-process loop's estimate (one start: no random starts to seed differently) to
    1e-10, and the same total cost; one iterate per finished block."""
    from framework.executor import DaskExecutor, SerialExecutor
    basis, system, _ = _two_block_system(np.random.default_rng(3))
    kw = dict(segments_params=[[0, 1], [2, 3]], x0=np.full(4, 0.5), starts=1)
    loop = solve_polynomial(system, basis, **kw)
    factory = SerialExecutor if where == "serial" else (lambda: DaskExecutor(n_workers=2))
    tasks = solve_polynomial(system, basis, executor=factory, **kw)
    np.testing.assert_allclose(tasks.estimate, loop.estimate, atol=1e-10)
    np.testing.assert_allclose(tasks.cost, loop.cost, rtol=1e-12)
    assert len(tasks.iterates) == 2 * system.n_channels and tasks.n_evals == loop.n_evals


def test_a_forked_child_runs_threads_of_its_own(monkeypatch):
    """A process forked after the pool started has none of its threads: it forgets the parent's
    pool (``os.register_at_fork``) and starts its own, which runs the tasks."""
    import multiprocessing
    import framework.threads as threads
    monkeypatch.setattr(threads, "cores", lambda: 2)
    assert threads.run_threads([lambda: 1, lambda: 2]) == [1, 2]          # the parent's pool exists
    if "fork" not in multiprocessing.get_all_start_methods():
        pytest.skip("no fork on this platform")
    with multiprocessing.get_context("fork").Pool(1) as pool:
        assert pool.apply(_two_tasks_on_threads) == (True, [3, 4])


def _two_tasks_on_threads():
    import framework.threads as threads
    threads.cores = lambda: 2
    forgotten = threads._POOL is None
    return forgotten, threads.run_threads([lambda: 3, lambda: 4])
