"""A Gram system held dense (methods.symbolic.system.dense_gram): every step of a fit gives what
the same system held as sparse triangles gives. The sparse steps are the reference (an
independent implementation: scipy's sparse products and connected components); tolerances are
float64 rounding of sums over at most 40 terms of order 1 (1e-12)."""
import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from methods.symbolic.survey.known import Substitution
from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.cost import ChannelCost
from methods.symbolic.system.dense_gram import components
from methods.symbolic.system.gram import GramSystem
from methods.symbolic.system.upper_triangle import dense_triangle
from methods.symbolic.uncertainty.observability import observable_parameters, restrict_system

TOL = dict(rtol=1e-12, atol=1e-12)


def _pair(seed: int = 0):
    """The same system dense and sparse: 3 channels over the monomials of 3 parameters of degree
    2, G symmetric and indefinite in two components (the monomials holding parameter 2 apart
    from the rest), one monomial without pixels (a zero row and column)."""
    rng = np.random.default_rng(seed)
    basis = MonomialBasis(3, 2)
    N = basis.size
    with_2 = np.any(basis.digits == 3, axis=1)
    block = with_2[:, None] == with_2[None, :]
    empty = N - 1
    G = []
    for _ in range(3):
        a = rng.normal(size=(N, N))
        g = (a + a.T) * block
        g[empty, :] = g[:, empty] = 0.0
        G.append(g)
    G = np.stack(G)
    b, yy = rng.normal(size=(3, N)), rng.uniform(1.0, 2.0, 3)
    b[:, empty] = 0.0
    dense = GramSystem.from_dense(G.copy(), b.copy(), yy.copy(), 50, basis.codes)
    sparse = GramSystem([sp.csr_matrix(g) for g in G], b.copy(), yy.copy(), 50, basis.codes)
    return dense, sparse, basis


def _whole(s: GramSystem) -> np.ndarray:
    return np.stack([s.matrix(c).toarray() for c in range(s.n_channels)])


def test_dense_system_reads_as_the_sparse_one():
    dense, sparse, _ = _pair()
    assert dense.dense is not None and sparse.dense is None
    assert dense.nnz == sparse.nnz
    np.testing.assert_array_equal(dense.used_monomials(), sparse.used_monomials())
    np.testing.assert_array_equal(dense.diagonals(), np.stack([g.diagonal() for g in sparse.G]))
    for c in range(3):
        assert (dense.G[c] != sparse.G[c]).nnz == 0          # the triangle cut on first use
    mu = np.random.default_rng(1).normal(size=(3, dense.n_monomials))
    np.testing.assert_allclose(dense.cost(mu), sparse.cost(mu), **TOL)
    assert not dense.dense[0].flags.writeable                  # shared by the systems made from it


@pytest.mark.parametrize("limit", [1000, 4])
def test_dense_psd_equals_the_sparse_one(limit):
    """Projected component by component (6, 3 and 1 monomials; the 6 left as they are under
    ``limit`` 4)."""
    dense, sparse, _ = _pair()
    pd, ps = dense.psd(limit), sparse.psd(limit)
    assert pd.dense is not None
    assert pd.psd_skipped == ps.psd_skipped == ((6, 6, 6) if limit == 4 else ())
    np.testing.assert_allclose(np.stack(pd.dense), _whole(ps), **TOL)
    np.testing.assert_allclose(pd.b, ps.b, **TOL)
    if limit == 1000:
        assert min(np.linalg.eigvalsh(d)[0] for d in pd.dense) > -1e-10
    np.testing.assert_array_equal(_whole(dense), np.stack(dense.dense))    # the input left as it was


def test_dense_restriction_reindexing_and_substitution_equal_the_sparse_ones():
    dense, sparse, basis = _pair()
    keep = np.array([True, True, False])
    (rd, bd, id_), (rs, bs, is_) = restrict_system(dense, basis, keep), restrict_system(sparse, basis, keep)
    np.testing.assert_array_equal(id_, is_)
    np.testing.assert_allclose(np.stack(rd.dense), _whole(rs), **TOL)
    np.testing.assert_array_equal(observable_parameters(dense, basis), observable_parameters(sparse, basis))
    wider = np.union1d(basis.codes, basis.codes.max() + np.arange(1, 4))
    np.testing.assert_allclose(np.stack(dense.reindexed(wider).dense), _whole(sparse.reindexed(wider)), **TOL)
    values = np.full((3, 3), np.nan)
    values[1] = [0.5, 0.4, 0.3]
    sub = Substitution.build(basis.codes, 3, 2, values)
    kd, ks = sub.system(dense), sub.system(sparse)
    assert kd.dense is not None
    np.testing.assert_allclose(np.stack(kd.dense), _whole(ks), **TOL)
    np.testing.assert_allclose(kd.b, ks.b, **TOL)


def test_dense_cost_equals_the_sparse_one():
    """Value, gradient and Hessian of each channel's cost, from the dense matrix (the survey's
    full system) and from the triangle."""
    dense, sparse, basis = _pair()
    x = np.array([0.3, 0.6, 0.2])
    for c in range(3):
        cd, cs = ChannelCost(dense, basis, c), ChannelCost(sparse, basis, c)
        assert cd.G is None                 # the dense products, from the system's matrix
        fd, gd = cd(x)
        fs, gs = cs(x)
        np.testing.assert_allclose(fd, fs, **TOL)
        np.testing.assert_allclose(gd, gs, **TOL)
        np.testing.assert_allclose(cd.hessian(x), cs.hessian(x), **TOL)


def test_adding_to_a_dense_system_makes_it_sparse():
    dense, sparse, _ = _pair()
    other = _pair(seed=3)[1]
    dense += other
    sparse += other
    assert dense.dense is None
    np.testing.assert_allclose(_whole(dense), _whole(sparse), **TOL)


def test_components_equal_scipys():
    """Labels in the order of first rows; the partition scipy's ``connected_components`` finds."""
    rng = np.random.default_rng(0)
    for density in (0.0, 0.002, 0.01, 0.3):
        a = rng.uniform(size=(120, 120)) < density
        pattern = a | a.T
        labels = components(pattern)
        n, expected = connected_components(sp.csr_matrix(pattern), directed=False)
        assert labels.max() + 1 == n
        # the same partition: a one-to-one map between the two labellings
        pairs = np.unique(np.stack([labels, expected]), axis=1)
        assert pairs.shape[1] == n
        assert np.all(np.diff(np.unique(labels, return_index=True)[1]) > 0)   # first rows in order
    np.testing.assert_array_equal(components(np.eye(4, dtype=bool)), [0, 1, 2, 3])
    np.testing.assert_array_equal(components(np.ones((3, 3), bool)), [0, 0, 0])


def test_dense_triangle_of_the_lazy_triangles():
    dense, _, _ = _pair()
    assert dense.G.cut() == [None, None, None]
    g = dense.G[1]
    assert dense.G[1] is g and dense.G.cut()[1] is g and (g != dense_triangle(dense.dense[1])).nnz == 0
    assert dense.nbytes() > sum(d.nbytes for d in dense.dense)
