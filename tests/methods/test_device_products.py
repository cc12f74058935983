"""device_products: CSR (and factored) matrices times dense ones on the Dr.Jit device (the tests'
``llvm_ad_rgb``), against scipy's products.

The device sums each entry's terms in scipy's order, one product and one sum at a time: on the CPU
this was written on the results are scipy's bits. A CPU whose compiler fuses the product and
the sum (FMA) rounds each term once instead of twice, so the tests allow 1e-13 of the entry's
sum of absolute terms (``|m| @ |x|``): a few units in the last place of the partial sums.
"""
from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest
import scipy.sparse as sp

from methods.symbolic.system.device_products import device_products
from methods.symbolic.system.pixel_matrices import FactoredColumns, expanded_columns


def _close(got: np.ndarray, m, x: np.ndarray) -> None:
    """``got`` equals ``m @ x`` to 1e-13 of ``|m| @ |x|`` (the module's docstring)."""
    m = m.expanded() if isinstance(m, FactoredColumns) else m
    assert got.shape == (m @ x).shape
    np.testing.assert_allclose(got, m @ x, rtol=0, atol=1e-13 * (abs(m) @ np.abs(x)).max())


def _matrix(rng, n: int, N: int, density: float) -> sp.csr_matrix:
    """A random CSR matrix with some empty rows, as a tile's dark pixels leave them."""
    m = sp.random(n, N, density=density, format="csr", random_state=rng)
    m[rng.integers(0, n, n // 5)] = 0
    m.eliminate_zeros()
    return m


def test_products_equal_scipys():
    """Vectors and matrices, empty rows, unsorted indices, several products in one evaluation."""
    rng = np.random.default_rng(3)
    m = _matrix(rng, 300, 40, 0.15)
    shuffled = m.copy()                                  # each row's entries in reverse order
    for i in range(m.shape[0]):
        lo, hi = m.indptr[i], m.indptr[i + 1]
        shuffled.indices[lo:hi], shuffled.data[lo:hi] = m.indices[lo:hi][::-1], m.data[lo:hi][::-1]
    shuffled.has_sorted_indices = False
    x, v = rng.normal(size=(40, 6)), rng.normal(size=40)
    got = device_products([(m, x), (m, v), (shuffled, x)])
    for g, (a, b) in zip(got, [(m, x), (m, v), (shuffled, x)]):
        _close(g, a, b)
    assert np.abs(got[0]).max() > 0


def test_factored_products_equal_the_expanded_ones():
    """A lens's factored matrix (two scaled copies of each column) against its expanded matrix."""
    rng = np.random.default_rng(4)
    m = _matrix(rng, 200, 30, 0.2)
    scales, columns = rng.uniform(0.5, 1.5, (2, 200)), rng.permutation(60).reshape(2, 30)
    factored = FactoredColumns(m, scales, columns, 60)
    x = rng.normal(size=(60, 5))
    got, = device_products([(factored, x)])
    _close(got, factored, x)
    np.testing.assert_allclose(got, expanded_columns(m, scales, columns, 60) @ x, rtol=1e-12, atol=1e-12)


def test_empty_products():
    """No rows, no stored entries, no columns: zeros of the right shape."""
    rng = np.random.default_rng(5)
    empty_rows = sp.csr_matrix((0, 7))
    no_entries = sp.csr_matrix((9, 7))
    got = device_products([(empty_rows, rng.normal(size=(7, 3))), (no_entries, rng.normal(size=(7, 3))),
                           (no_entries, np.zeros((7, 0)))])
    assert [g.shape for g in got] == [(0, 3), (9, 3), (9, 0)]
    assert not np.any(got[1])


def test_device_products_errors():
    """One bad input each: shapes, the matrix's format, x's dimensions, no JIT variant active."""
    m = sp.csr_matrix(np.eye(4))
    with pytest.raises(ValueError, match="do not match"):
        device_products([(m, np.ones((5, 2)))])
    with pytest.raises(ValueError, match="CSR or FactoredColumns"):
        device_products([(m.tocoo(), np.ones((4, 2)))])
    with pytest.raises(ValueError, match="vector or a matrix"):
        device_products([(m, np.ones((4, 2, 2)))])
    variant = mi.variant()
    mi.set_variant("scalar_rgb")
    try:
        with pytest.raises(ValueError, match="llvm_\\* or cuda_\\*"):
            device_products([(m, np.ones(4))])
    finally:
        mi.set_variant(variant)
