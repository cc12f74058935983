"""GramSystem: normal equations of the p = 2 cost (paper eq. 6)."""
import numpy as np
import pytest

from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.gram import GramSystem


def _data(seed=0, n=300, N_e=20, C=3, density=0.05):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, N_e, C)) * (rng.uniform(size=(n, N_e, C)) < density)
    X[:, 0, :] = rng.uniform(size=(n, C))
    y = rng.uniform(size=(n, C))
    return X.astype(np.float32), y


def _dense(s: GramSystem) -> np.ndarray:
    """The dense ``(C, N, N)`` reference of a system's sparse G."""
    return np.stack([s.matrix(c).toarray() for c in range(s.n_channels)])


def test_tiles_equal_all_at_once():
    """Accumulating two tiles (and adding systems) equals one accumulation, to 1e-12 relative."""
    X, y = _data()
    full = GramSystem.zeros(20, 3).accumulate(X, y)
    tiled = GramSystem.zeros(20, 3).accumulate(X[:120], y[:120]).accumulate(X[120:], y[120:])
    summed = GramSystem.zeros(20, 3).accumulate(X[:77], y[:77]) + \
        GramSystem.zeros(20, 3).accumulate(X[77:], y[77:])
    for s in (tiled, summed):
        assert s.n_pixels == full.n_pixels == 300
        np.testing.assert_allclose(_dense(s), _dense(full), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(s.b, full.b, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(s.yy, full.yy, rtol=1e-12)
    # G is the dense product Xᵀ X (float64)
    Xd = X.astype(np.float64)
    np.testing.assert_allclose(_dense(full)[1], Xd[:, :, 1].T @ Xd[:, :, 1], rtol=1e-12, atol=1e-12)


def test_sums_over_different_monomials_in_place_and_not():
    """Systems over different codes: ``a + b`` leaves both as they were, ``a += b`` gives the same
    bits in ``a`` (its matrices replaced channel by channel), and both equal the dense sum of the
    two systems spread over the union of the codes."""
    X, y = _data(2)
    a = GramSystem.zeros(np.arange(0, 20, 2), 3).accumulate(X[:150, ::2], y[:150])
    b = GramSystem.zeros(np.arange(0, 20, 3), 3).accumulate(X[150:, ::3], y[150:])
    a_before, b_before = _dense(a).copy(), _dense(b).copy()
    summed = a + b
    np.testing.assert_array_equal(_dense(a), a_before)
    np.testing.assert_array_equal(_dense(b), b_before)
    codes = np.union1d(a.codes, b.codes)
    expected = np.zeros((3, len(codes), len(codes)))
    for s in (a, b):
        at = np.searchsorted(codes, s.codes)
        expected[:, at[:, None], at[None, :]] += _dense(s)
    np.testing.assert_array_equal(summed.codes, codes)
    np.testing.assert_allclose(_dense(summed), expected, rtol=1e-15, atol=0)
    a += b
    np.testing.assert_array_equal(a.codes, codes)
    np.testing.assert_array_equal(_dense(a), _dense(summed))
    np.testing.assert_array_equal(a.b, summed.b)
    assert a.n_pixels == 300


def test_cost_equals_direct_sum_of_squares():
    """cost(μ) = Σ_i (γ_i·μ - y_i)² computed directly per channel, to 1e-9 relative."""
    X, y = _data(1, N_e=10)
    b = MonomialBasis(3, 2)        # N_e = 10
    s = GramSystem.zeros(10, 3).accumulate(X, y)
    rng = np.random.default_rng(2)
    rho = rng.uniform(size=(3, 3))
    mu = np.stack([b.evaluate(rho[:, c]) for c in range(3)])
    direct = np.array([((X[:, :, c].astype(np.float64) @ mu[c] - y[:, c]) ** 2).sum() for c in range(3)])
    np.testing.assert_allclose(s.cost(mu), direct, rtol=1e-9)


def test_mask():
    X, y = _data(2)
    m = np.arange(300) % 3 == 0
    a = GramSystem.zeros(20, 3).accumulate(X, y, mask=m)
    b = GramSystem.zeros(20, 3).accumulate(X[m], y[m])
    np.testing.assert_allclose(_dense(a), _dense(b))
    np.testing.assert_allclose(a.b, b.b)
    assert a.n_pixels == 100


def test_cross_gram_removes_monte_carlo_bias():
    """Two independent noisy estimates A, B of the coefficients Γ (noise std σ, n pixels):
    E[AᵀA] = ΓᵀΓ + nσ²I (the bias that shrinks estimates), E[½(AᵀB + BᵀA)] = ΓᵀΓ.

    n = 20000, σ = 0.1, Γ ~ U(0, 0.1): the plain bias on the diagonal is nσ² = 200 (its
    fluctuation 2σ‖Γ‖ + σ²√(2n) ≈ 3.6 fits in rtol 0.1); the cross estimate's error has std
    σ‖Γ‖ + σ²√n ≈ 2.2 per entry, so 10 (> 4 std) bounds it.
    """
    rng = np.random.default_rng(0)
    n, N_e, sigma = 20000, 6, 0.1
    gamma = 0.1 * rng.random((n, N_e, 1))
    a = gamma + rng.normal(0, sigma, gamma.shape)
    b = gamma + rng.normal(0, sigma, gamma.shape)
    y = rng.random((n, 1))
    exact = gamma[:, :, 0].T @ gamma[:, :, 0]
    plain = GramSystem.zeros(N_e, 1).accumulate(a, y)
    cross = GramSystem.zeros(N_e, 1).accumulate(a, y, coeffs_b=b)
    np.testing.assert_allclose(np.diag(_dense(plain)[0] - exact), n * sigma**2, rtol=0.1)
    assert np.abs(_dense(cross)[0] - exact).max() < 10.0
    np.testing.assert_allclose(cross.b[0], 0.5 * (a[:, :, 0] + b[:, :, 0]).T @ y[:, 0])


def test_psd_projection():
    """GramSystem.psd: PSD result, a PSD input unchanged (1e-10), and on a noisy symmetric
    estimate of a rank-2 PSD matrix the Frobenius distance to it shrinks (projection onto a
    convex set holding the truth is non-expansive); b and yy untouched."""
    rng = np.random.default_rng(0)
    X = rng.normal(size=(2, 6))
    truth = X.T @ X
    noise = rng.normal(scale=0.5, size=(6, 6))
    noisy = truth + 0.5 * (noise + noise.T)
    s = GramSystem([truth, noisy], rng.normal(size=(2, 6)), np.array([1.0, 2.0]), 10)
    p = s.psd()
    G = _dense(p)
    assert np.linalg.eigvalsh(G[1]).min() > -1e-10
    np.testing.assert_allclose(G[0], truth, atol=1e-10)
    assert np.linalg.norm(G[1] - truth) < np.linalg.norm(noisy - truth)
    np.testing.assert_array_equal(p.b, s.b)
    np.testing.assert_array_equal(p.yy, s.yy)


@pytest.mark.parametrize("negatives", [3, 37])
def test_psd_projection_from_the_smaller_eigenspace(negatives):
    """``psd_projection`` equals ``V max(λ, 0) Vᵀ`` (to 1e-12 of eigenvalues of order 1) whether
    it subtracts the few negative eigenvalues' part or sums the few positive ones'."""
    from methods.symbolic.system.dense_gram import psd_projection
    rng = np.random.default_rng(negatives)
    Q, _ = np.linalg.qr(rng.normal(size=(40, 40)))
    lam = np.concatenate([-rng.uniform(0.1, 2.0, negatives), rng.uniform(0.1, 2.0, 40 - negatives)])
    m = (Q * lam) @ Q.T
    expected = (Q * np.maximum(lam, 0.0)) @ Q.T
    np.testing.assert_allclose(psd_projection(m), expected, rtol=0, atol=1e-12)


def test_dense_triangle_equals_scipy_triu():
    """``dense_triangle`` gives scipy's ``csr_matrix(np.triu(m))`` exactly, zeros left out."""
    import scipy.sparse as sp

    from methods.symbolic.system.upper_triangle import dense_triangle
    m = np.random.default_rng(2).normal(size=(30, 30))
    m[3, 7] = m[0, 0] = 0.0
    out, ref = dense_triangle(m), sp.csr_matrix(np.triu(m))
    assert out.nnz == ref.nnz == 30 * 31 // 2 - 2
    assert np.array_equal(out.indptr, ref.indptr) and np.array_equal(out.indices, ref.indices)
    assert np.array_equal(out.data, ref.data)


def test_psd_of_one_component_equals_the_general_path(monkeypatch):
    """A G of one connected component and 1 x 1 ones (the fast path) gives the entries of the
    general path (two components): the component projected, a 1 x 1 one max(g_ii, 0); [[1, 2],
    [2, 1]] (eigenvalues 3, -1) projects to 1.5 everywhere."""
    from methods.symbolic.system.gram import _psd_components
    import scipy.sparse as sp
    rng = np.random.default_rng(8)
    a = rng.normal(size=(12, 12))
    sym = a + a.T
    whole, _ = _psd_components(sp.csr_matrix(np.triu(sym)), 100)
    padded = np.zeros((13, 13))
    padded[:12, :12] = sym
    padded[12, 12] = -1.0
    parts, _ = _psd_components(sp.csr_matrix(np.triu(padded)), 100)
    np.testing.assert_allclose(parts.toarray()[:12, :12], whole.toarray(), rtol=0, atol=1e-12)
    assert parts[12, 12] == 0.0 and parts.nnz == whole.nnz
    padded[12, 12] = 2.0
    parts, _ = _psd_components(sp.csr_matrix(np.triu(padded)), 100)
    assert parts[12, 12] == 2.0 and parts.nnz == whole.nnz + 1
    np.testing.assert_allclose(parts.toarray()[:12, :12], whole.toarray(), rtol=0, atol=1e-12)
    three = np.zeros((14, 14))                         # two components: the general path
    three[:12, :12], three[12:, 12:] = sym, [[1.0, 2.0], [2.0, 1.0]]
    parts, _ = _psd_components(sp.csr_matrix(np.triu(three)), 100)
    np.testing.assert_allclose(parts.toarray()[:12, :12], whole.toarray(), rtol=0, atol=1e-12)
    np.testing.assert_allclose(parts.toarray()[12:, 12:], [[1.5, 1.5], [0.0, 1.5]], atol=1e-12)


def test_psd_channels_sharing_a_pattern_equal_one_at_a_time():
    """``GramSystem.psd`` searches the components once for channels storing entries at the same
    places: the result equals each channel projected on its own (to the bit), with channels of
    the same pattern and of another one (a coupling entry left out of the last channel)."""
    from methods.symbolic.system.gram import _psd_components
    import scipy.sparse as sp
    rng = np.random.default_rng(9)
    blocks = []
    for seed in range(3):
        a = rng.normal(size=(10, 10))
        m = np.zeros((10, 10))
        m[:4, :4], m[4:, 4:] = (a + a.T)[:4, :4], (a + a.T)[4:, 4:]      # two components each
        blocks.append(m)
    blocks[2][0, 1] = blocks[2][1, 0] = 0.0                              # another pattern
    s = GramSystem([sp.csr_matrix(np.triu(m)) for m in blocks], rng.normal(size=(3, 10)), np.ones(3), 10)
    together = s.psd()
    for g, m in zip(together.G, blocks):
        alone, _ = _psd_components(sp.csr_matrix(np.triu(m)), 4000)
        assert (g != alone).nnz == 0


@pytest.mark.parametrize("n", [1, 5, 128, 300])
def test_dense_symmetric_mirrors_the_triangle(n):
    """``dense_symmetric`` of a triangle equals ``U + Uᵀ - diag(U)`` summed densely by numpy, to
    the bit (copies only), for sizes below, at and across its block of rows."""
    import scipy.sparse as sp

    from methods.symbolic.system.upper_triangle import dense_symmetric
    m = np.random.default_rng(n).normal(size=(n, n))
    u = np.triu(m)
    expected = u + u.T - np.diag(np.diag(u))
    assert np.array_equal(dense_symmetric(sp.csr_matrix(u)), expected)
