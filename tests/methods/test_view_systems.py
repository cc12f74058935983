"""The field path's sums over views, on threads: the same numbers as one view and one chunk at a time."""
import operator
from functools import reduce

import numpy as np
import pytest
import scipy.sparse as sp

from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.coefficients import TiledCoefficients, ViewCoefficients
from methods.symbolic.system.view_systems import summed_views, weighted_system
from methods.symbolic.uncertainty import sandwich_meat
from methods.symbolic.uncertainty.sandwich_meat import score_meat

BASIS = MonomialBasis(3, 2)
C = 3


def _block(rng, n: int) -> ViewCoefficients:
    """Two noisy half-sample estimates of sparse coefficients over a random subset of ``BASIS``."""
    keep = np.union1d([0], rng.choice(np.arange(1, BASIS.size), 6, replace=False))
    gamma = [sp.random(n, len(keep), density=0.4, format="csr", random_state=rng) for _ in range(C)]
    noisy = lambda: [g + g.multiply(rng.normal(0, 0.1, g.shape)) for g in gamma]   # noqa: E731
    return ViewCoefficients(noisy(), noisy(), 0.5, BASIS.codes[keep])


def _views(seed: int, n_views: int) -> list:
    """``(coefficients, y, weights)`` of views: whole ones and tiled ones of two blocks."""
    rng = np.random.default_rng(seed)
    views = []
    for v in range(n_views):
        if v % 2:
            coeffs = TiledCoefficients([0, 30], [_block(rng, 30), _block(rng, 20)], 50)
        else:
            coeffs = _block(rng, 50)
        views.append((coeffs, rng.uniform(0, 1, (50, C)), rng.uniform(0, 1, 50) if v % 3 else None))
    return views


def _same_bits(a, b) -> None:
    assert np.array_equal(a.codes, b.codes) and a.n_pixels == b.n_pixels
    for ga, gb in zip(a.G, b.G):
        for x, y in ((ga.indptr, gb.indptr), (ga.indices, gb.indices), (ga.data, gb.data)):
            assert np.array_equal(x, y)
    assert np.array_equal(a.b, b.b) and np.array_equal(a.yy, b.yy)


@pytest.mark.parametrize("n_views", [1, 2, 5])
def test_summed_views_are_the_views_added_in_turn(n_views):
    """Two views at a time on threads (an odd one left alone): the same bits as each view's
    system formed and added in view order."""
    views = _views(4, n_views)
    _same_bits(summed_views(views), reduce(operator.iadd, (weighted_system(*v) for v in views)))


def test_summed_views_one_at_a_time_above_the_bound(monkeypatch):
    """A first view's system above the bound: the others one at a time, the same bits."""
    from methods.symbolic.system import gram
    views = _views(5, 4)
    with monkeypatch.context() as m:
        m.setattr(gram, "PARALLEL_CHANNEL_BYTES", 0)
        big = summed_views(views)
    _same_bits(big, reduce(operator.iadd, (weighted_system(*v) for v in views)))


@pytest.mark.parametrize("clustered", [False, True])
def test_score_meat_in_pairs_of_chunks(monkeypatch, clustered):
    """Rows scored in chunks, two chunks at a time (three chunks per view, one across a tile's
    edge): the meat of every row scored at once, to 1e-12 relative (only the order of the sums
    differs), with and without clusters."""
    views = _views(6, 3)
    rho = np.random.default_rng(7).uniform(0.2, 0.8, (BASIS.n_params, C))
    clusters = [np.arange(50) // 7 for _ in views] if clustered else None
    whole = score_meat(BASIS, rho, views, np.arange(BASIS.size), BASIS.codes, clusters=clusters)
    with monkeypatch.context() as m:
        m.setattr(sandwich_meat, "SCORE_CHUNK_NNZ", 60)
        assert len(sandwich_meat._row_chunks(views[0][0])) >= 3
        chunked = score_meat(BASIS, rho, views, np.arange(BASIS.size), BASIS.codes, clusters=clusters)
    np.testing.assert_allclose(chunked, whole, rtol=1e-12, atol=1e-12 * np.abs(whole).max())
