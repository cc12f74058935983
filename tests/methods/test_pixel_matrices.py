"""Row scaling and column interleaving of per-pixel coefficient matrices
(:mod:`methods.symbolic.system.pixel_matrices`) against scipy's general products, which they replace."""
import numpy as np
import scipy.sparse as sp

import pickle

import pytest

from methods.symbolic.system.pixel_matrices import (FactoredColumns, expanded_columns, product_into, scale_columns,
                                                    scale_rows, stored_per_row)


def test_scale_rows_by_hand():
    """[[1, 2], [0, 3]] with rows times (2, 0): [[2, 4], [0, 0]], the zeroed row's entries dropped."""
    m = sp.csr_matrix(np.array([[1.0, 2.0], [0.0, 3.0]]))
    out = scale_rows(m, np.array([2.0, 0.0]))
    assert out.toarray().tolist() == [[2.0, 4.0], [0.0, 0.0]]
    assert out.nnz == 2 and m.toarray().tolist() == [[1.0, 2.0], [0.0, 3.0]]     # m untouched


def test_scale_rows_equals_the_diagonal_product():
    m = sp.random(60, 40, density=0.15, format="csr", random_state=3)
    s = np.random.default_rng(3).normal(size=60)
    s[[4, 9]] = 0.0
    ref = (sp.diags(s) @ m).tocsr()
    out = scale_rows(m, s)
    assert out.nnz == ref.nnz and np.array_equal(out.toarray(), ref.toarray())


def test_expanded_columns_equals_scaled_copies_stacked_then_permuted():
    """Bit for bit the canonical CSR of ``hstack([diag(s_t) m])[:, order]`` (what the vignetting's
    expansion built before) once its rows are sorted, rows scaled to 0 dropped; left unsorted, and
    marked so (scipy then sorts where an operation needs it)."""
    rng = np.random.default_rng(5)
    m = sp.random(30, 20, density=0.3, format="csr", random_state=5)
    scales = rng.normal(size=(3, 30))
    scales[1, 4] = 0.0
    order = rng.permutation(60)
    position = np.empty(60, np.int64)
    position[order] = np.arange(60)
    ref = sp.csr_matrix(sp.hstack([sp.diags(s) @ m for s in scales], format="csc")[:, order])
    out = expanded_columns(m, scales, position.reshape(3, 20), 60)
    assert not out.has_sorted_indices
    out = out.sorted_indices()
    for a, b in ((out.indptr, ref.indptr), (out.indices, ref.indices), (out.data, ref.data)):
        assert np.array_equal(a, b)


def test_expanded_columns_by_hand():
    """m = [[1, 0], [0, 2], [0, 0]], copies scaled by rows (1, 1, 1) and (3, 0, 1) into columns
    (1, 3) and (2, 0): [[0, 1, 3, 0], [0, 0, 0, 2], [0, 0, 0, 0]]."""
    m = sp.csr_matrix(np.array([[1.0, 0.0], [0.0, 2.0], [0.0, 0.0]]))
    out = expanded_columns(m, np.array([[1.0, 1.0, 1.0], [3.0, 0.0, 1.0]]), np.array([[1, 3], [2, 0]]), 4)
    assert out.toarray().tolist() == [[0.0, 1.0, 3.0, 0.0], [0.0, 0.0, 0.0, 2.0], [0.0, 0.0, 0.0, 0.0]]


def test_scale_columns_by_hand():
    """[[1, 2], [0, 3]] with columns times (0.5, 0): [[0.5, 0], [0, 0]]."""
    m = sp.csr_matrix(np.array([[1.0, 2.0], [0.0, 3.0]]))
    out = scale_columns(m, np.array([0.5, 0.0]))
    assert out.toarray().tolist() == [[0.5, 0.0], [0.0, 0.0]] and out.nnz == 1
    big = sp.random(40, 25, density=0.2, format="csr", random_state=2)
    f = np.random.default_rng(2).normal(size=25)
    assert np.array_equal(scale_columns(big, f).toarray(), (big @ sp.diags(f)).toarray())


def _factored(seed: int = 7):
    """A 30 x 20 matrix expanded into three copies over 60 columns, a row's copy scaled to 0."""
    rng = np.random.default_rng(seed)
    m = sp.random(30, 20, density=0.3, format="csr", random_state=seed)
    scales = rng.normal(size=(3, 30))
    scales[1, 4] = 0.0
    columns = rng.permutation(60).reshape(3, 20)
    return FactoredColumns(m, scales, columns, 60), expanded_columns(m, scales, columns, 60).toarray()


@pytest.mark.parametrize("operand", ["vector", "dense", "sparse"])
def test_factored_product_equals_the_expanded_one(operand):
    """``E x`` from the factors equals the expanded matrix's product to rounding (1e-12 of entries
    of order 1: a few sums of products of normal values), for a vector, a dense and a sparse ``x``."""
    E, ref = _factored()
    rng = np.random.default_rng(1)
    x = {"vector": rng.normal(size=60), "dense": rng.normal(size=(60, 5)),
         "sparse": sp.random(60, 5, density=0.3, format="csr", random_state=1)}[operand]
    out = E @ x
    expected = ref @ (x.toarray() if sp.issparse(x) else x)
    assert sp.issparse(out) == sp.issparse(x)
    np.testing.assert_allclose(out.toarray() if sp.issparse(out) else out, expected, rtol=0, atol=1e-12)
    assert E._expanded is None                       # nothing expanded for a product


def test_factored_transpose_and_rows():
    """``Eᵀ v`` and a row slice's products come from the factors; ``Eᵀ`` times a matrix, an index
    and any other attribute from the expanded matrix, made once."""
    E, ref = _factored()
    v = np.random.default_rng(2).normal(size=30)
    np.testing.assert_allclose(E.T @ v, ref.T @ v, rtol=0, atol=1e-12)
    rows = E[5:17]
    assert isinstance(rows, FactoredColumns) and rows.shape == (12, 60)
    np.testing.assert_allclose(rows @ np.ones(60), ref[5:17] @ np.ones(60), rtol=0, atol=1e-12)
    assert E._expanded is None and E.shape == (30, 60)
    assert np.array_equal(stored_per_row(E), 3 * E.m.indptr)
    np.testing.assert_allclose((E.T @ sp.csr_matrix(np.eye(30))).toarray(), ref.T)
    assert np.array_equal(E.toarray(), ref) and E._expanded is not None
    assert np.array_equal(E[[0, 3]].toarray(), ref[[0, 3]])
    assert np.array_equal(stored_per_row(E.expanded()), E.indptr)


def test_factored_columns_pickle():
    """A worker may receive it: it pickles with its factors, unexpanded."""
    E, ref = _factored()
    back = pickle.loads(pickle.dumps(E))
    assert back._expanded is None and np.array_equal(back.toarray(), ref)


def test_moved_columns_equals_the_permutation_product():
    """``moved_columns(m, position, f)`` equals ``m P f`` (P[j, position[j]] = 1) exactly, its rows
    left unsorted; a factor 0 leaves no stored entry."""
    from methods.symbolic.system.pixel_matrices import moved_columns
    m = sp.random(25, 12, density=0.3, format="csr", random_state=3)
    position = np.random.default_rng(3).permutation(12)
    P = sp.csr_matrix((np.ones(12), (np.arange(12), position)), shape=(12, 12))
    out = moved_columns(m, position, 2.5)
    assert not out.has_sorted_indices
    assert np.array_equal(out.toarray(), (m @ P).toarray() * 2.5)
    assert moved_columns(m, position, 0.0).nnz == 0


def _product_operands(seed: int):
    """A CSR ``p`` (30 x 40) with empty rows and an explicit zero, and ``q`` (40 x 25) with
    unsorted indices (as :func:`expanded_columns` leaves them)."""
    rng = np.random.default_rng(seed)
    p = sp.random(30, 40, density=0.15, format="csr", random_state=rng)
    p.data[p.indptr[3]:p.indptr[4]] = 0.0
    p.eliminate_zeros()                                # row 3 empty
    p.data[0] = 0.0                                    # stored, but zero
    q = expanded_columns(sp.random(40, 5, density=0.5, format="csr", random_state=rng),
                         rng.uniform(0.5, 2.0, (5, 40)), np.arange(25).reshape(5, 5), 25)
    return p, q


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_product_into_adds_the_product(seed):
    """``dense += p @ q`` in place: against numpy's product of the dense operands, to 1e-12."""
    p, q = _product_operands(seed)
    start = np.random.default_rng(9).standard_normal((30, 25))
    dense = start.copy()
    product_into(dense, p, q)
    np.testing.assert_allclose(dense, start + p.toarray() @ q.toarray(), rtol=1e-12, atol=1e-12)


def test_product_into_finds_scipys_kernel():
    """The kernel is scipy's private ``_sparsetools.csr_matmat``: a scipy that moved it would
    make every product take the fallback's two passes unnoticed, so its absence fails here."""
    from methods.symbolic.system.pixel_matrices import _product_kernel
    assert _product_kernel() is not None


def test_product_into_above_the_bound_takes_scipys_product(monkeypatch):
    """Above the bound the product is scipy's ``p @ q``: the same sum, bit for bit (the same
    kernel on the same operands)."""
    import methods.symbolic.system.pixel_matrices as pm
    p, q = _product_operands(3)
    direct = np.zeros((30, 25))
    product_into(direct, p, q)
    monkeypatch.setattr(pm, "PRODUCT_BOUND_ENTRIES", 0)
    fallback = np.zeros((30, 25))
    product_into(fallback, p, q)
    np.testing.assert_array_equal(direct, fallback)


def test_product_into_errors():
    """The dense target must be C-contiguous and of the product's shape."""
    p, q = _product_operands(0)
    with pytest.raises(ValueError, match="C-contiguous 30 x 25"):
        product_into(np.zeros((25, 30)).T, p, q)
    with pytest.raises(ValueError, match="C-contiguous 30 x 25"):
        product_into(np.zeros((30, 26)), p, q)
