"""Row scaling and column interleaving of per-pixel coefficient matrices
(:mod:`methods.symbolic.system.sparse_rows`) against scipy's general products, which they replace."""
import numpy as np
import scipy.sparse as sp

from methods.symbolic.system.sparse_rows import interleaved_columns, scale_rows


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


def test_interleaved_columns_equals_hstack_then_permutation():
    """Bit for bit the canonical CSR of ``hstack(parts)[:, order]`` (what the vignetting's
    expansion built before), indices sorted within each row."""
    rng = np.random.default_rng(5)
    parts = [sp.random(30, 20, density=0.3, format="csr", random_state=k) for k in range(3)]
    order = rng.permutation(60)
    position = np.empty(60, np.int64)
    position[order] = np.arange(60)
    ref = sp.csr_matrix(sp.hstack(parts, format="csc")[:, order])
    out = interleaved_columns(parts, np.split(position, 3), 60)
    assert out.has_sorted_indices
    for a, b in ((out.indptr, ref.indptr), (out.indices, ref.indices), (out.data, ref.data)):
        assert np.array_equal(a, b)


def test_interleaved_columns_of_empty_rows():
    parts = [sp.csr_matrix((3, 2)), sp.csr_matrix(np.array([[0.0, 1.0], [0.0, 0.0], [2.0, 0.0]]))]
    out = interleaved_columns(parts, [np.array([1, 3]), np.array([2, 0])], 4)
    assert out.toarray().tolist() == [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 2.0, 0.0]]
