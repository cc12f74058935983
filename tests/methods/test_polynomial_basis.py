"""MonomialBasis (paper eq. 7-8, section 4.3)."""
from itertools import product
from math import comb

import numpy as np
import pytest

from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.trace.monomial_codes import monomial_columns, multiset_codes


@pytest.mark.parametrize("D,N", [(1, 1), (1, 4), (3, 2), (4, 3), (10, 3), (5, 0)])
def test_size_is_multiset_coefficient(D, N):
    """N_e = C(D+N, N) (paper 4.3; 286 for D=10, N=3); rows unique, degrees <= N, index 0 constant."""
    b = MonomialBasis(D, N)
    assert b.size == comb(D + N, N)
    assert b.exponents.shape == (b.size, D)
    assert len({tuple(e) for e in b.exponents}) == b.size
    assert b.exponents.sum(1).max() == N and (b.exponents >= 0).all()
    assert (b.exponents[0] == 0).all()
    if N >= 1:
        assert (b.exponents[1:D + 1] == np.eye(D, dtype=int)).all()


def test_paper_example_286():
    assert MonomialBasis(10, 3).size == 286


@pytest.mark.parametrize("D,N", [(1, 3), (3, 3), (4, 2), (2, 4)])
def test_multiset_codes_map_every_ordered_tuple(D, N):
    """Every ordered key (p_0..p_{d-1}), d <= N, maps to the code of the monomial with exponents =
    counts; the codes of all tuples are those of the full basis."""
    b = MonomialBasis(D, N)
    tuples = [t for d in range(N + 1) for t in product(range(D), repeat=d)]
    keys = np.array([sum((p + 1) * (D + 1) ** i for i, p in enumerate(t)) for t in tuples])
    codes = multiset_codes(keys, D, N)
    for t, code in zip(tuples, codes):
        m = int(np.searchsorted(b.codes, code))
        assert b.codes[m] == code
        assert (b.exponents[m] == np.bincount(np.array(t, int), minlength=D)).all()
    np.testing.assert_array_equal(np.unique(codes), b.codes)


def test_evaluate_jacobian_hessian_vs_finite_differences():
    """Jacobian/Hessian vs central differences (h=1e-6 / 1e-4; tolerance 1e-6 / 1e-5 absolute)."""
    rng = np.random.default_rng(3)
    b = MonomialBasis(4, 3)
    rho = rng.uniform(0.1, 0.9, 4)
    v = b.evaluate(rho)
    assert np.allclose(v, [np.prod(rho ** e) for e in b.exponents], rtol=1e-14)
    J = b.jacobian(rho)
    H = b.hessian(rho)
    h = 1e-6
    for k in range(4):
        e = np.zeros(4); e[k] = h
        fd = (b.evaluate(rho + e) - b.evaluate(rho - e)) / (2 * h)
        assert np.allclose(J[:, k], fd, atol=1e-6)
        h2 = 1e-4
        e2 = np.zeros(4); e2[k] = h2
        fdh = (b.jacobian(rho + e2) - b.jacobian(rho - e2)) / (2 * h2)
        assert np.allclose(H[:, :, k], fdh, atol=1e-5)
    # exact at zero: d(ρ0)/dρ0 = 1, d(ρ0²)/dρ0 = 0 at ρ = 0
    J0 = b.jacobian(np.zeros(4))
    assert J0[1, 0] == 1.0 and J0[b.index([0, 0]), 0] == 0.0
    assert b.evaluate(np.zeros(4))[0] == 1.0
    # the Hessian is symmetric, exact at zero: d²(ρ0ρ1)/dρ0dρ1 = 1
    assert np.array_equal(H, H.transpose(0, 2, 1))
    assert b.hessian(np.zeros(4))[b.index([0, 1]), 0, 1] == 1.0


def test_jacobian_t_dot_and_batched_evaluate():
    """jacobian_t_dot(μ, r) = J(ρ)ᵀ r (dense J as reference); batched evaluate = row by row."""
    rng = np.random.default_rng(4)
    b = MonomialBasis(5, 3)
    rho = rng.uniform(0, 1, (3, 5))
    r = rng.normal(size=b.size)
    for x in rho:
        np.testing.assert_allclose(b.jacobian_t_dot(x, r), b.jacobian(x).T @ r, rtol=1e-12)
    np.testing.assert_array_equal(b.evaluate(rho), np.stack([b.evaluate(x) for x in rho]))


def test_indices_inverts_exponents():
    """indices(exponents) is the row order itself; a row that is no monomial of the basis is refused."""
    b = MonomialBasis(4, 3)
    np.testing.assert_array_equal(b.indices(b.exponents), np.arange(b.size))
    assert b.indices([[1, 0, 2, 0]])[0] == b.index([0, 2, 2])
    with pytest.raises(ValueError, match="not a monomial"):
        b.indices([[2, 2, 0, 0]])            # degree 4 > N_max
    with pytest.raises(ValueError, match="not a monomial"):
        b.indices([[-1, 0, 0, 0]])


@pytest.mark.parametrize("D,N", [(5, 3), (200, 3)])   # a lookup table, then sorting (span > 2^22)
def test_monomial_columns_equal_the_codes_of_every_key(D, N):
    rng = np.random.default_rng(0)
    keys = rng.integers(0, (D + 1) ** N, 50_000)
    codes, cols = monomial_columns(keys, D, N)
    expected = multiset_codes(keys, D, N)
    np.testing.assert_array_equal(codes, np.unique(expected))
    np.testing.assert_array_equal(codes[cols], expected)


def test_emitter_columns_by_hand():
    """D = 2, N_max = 2, one unknown scale (G = 1): keys ``κ + g·3²``. κ = 2 + 1·3 is the path
    (ρ_1, ρ_0): multiset digits [1, 2], code 1 + 2·4 = 9 in base D + G + 1 = 4; with the scale
    (g = 1) its digit 3 is appended: 1 + 2·4 + 3·16 = 57. κ = 0 (a directly seen emitter):
    code 0, with the scale 3; κ = 1 (ρ_0 alone) with the scale: digits [1, 3], 1 + 3·4 = 13."""
    from methods.symbolic.trace.monomial_codes import emitter_columns
    keys = np.array([5, 5 + 9, 0, 9, 5 + 9, 1 + 9])
    codes, cols = emitter_columns(keys, 2, 2, 1)
    assert codes.tolist() == [0, 3, 9, 13, 57]
    assert codes[cols].tolist() == [9, 57, 0, 3, 57, 13]
