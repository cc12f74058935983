"""The field path's sums over views, on threads and dense: the same numbers as one view and one
chunk at a time; a lens's Gram matrix formed before the expansion, against the expanded one."""
import operator
from functools import reduce

import numpy as np
import pytest
import scipy.sparse as sp

from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.coefficients import TiledCoefficients, ViewCoefficients
from methods.symbolic.trace.monomial_codes import code_digits
from methods.symbolic.system import view_systems
from methods.symbolic.system.view_systems import summed_views, weighted_system
from methods.symbolic.uncertainty import sandwich_meat
from methods.symbolic.uncertainty.sandwich_meat import score_meat

BASIS = MonomialBasis(3, 2)
C = 3


def _block(rng, n: int, codes: np.ndarray = BASIS.codes) -> ViewCoefficients:
    """Two noisy half-sample estimates of sparse coefficients over a random subset of ``codes``
    (``BASIS``'s), the constant among them."""
    keep = np.union1d([0], rng.choice(np.arange(1, len(codes)), 6, replace=False))
    gamma = [sp.random(n, len(keep), density=0.4, format="csr", random_state=rng) for _ in range(C)]
    noisy = lambda: [g + g.multiply(rng.normal(0, 0.1, g.shape)) for g in gamma]   # noqa: E731
    return ViewCoefficients(noisy(), noisy(), 0.5, codes[keep])


#: the monomials of ``BASIS``'s three parameters coded over nine (three, then two lenses' three)
LENS_CODES = MonomialBasis(9, 2).codes[(code_digits(MonomialBasis(9, 2).codes, 9, 2) <= 3).all(axis=1)]


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


def _close(a, b, rtol: float = 1e-12) -> None:
    """Two systems equal up to the order of their sums: each matrix to ``rtol`` of its largest entry."""
    assert np.array_equal(a.codes, b.codes) and a.n_pixels == b.n_pixels
    for c in range(len(a.G)):
        ga, gb = a.G[c].toarray(), b.G[c].toarray()
        np.testing.assert_allclose(ga, gb, rtol=0, atol=rtol * np.abs(gb).max())
    np.testing.assert_allclose(a.b, b.b, rtol=0, atol=rtol * np.abs(b.b).max())
    np.testing.assert_allclose(a.yy, b.yy, rtol=rtol)


@pytest.mark.parametrize("n_views", [1, 2, 5])
def test_summed_views_are_the_views_added_in_turn(n_views):
    """As sparse systems, two views at a time on threads (an odd one left alone): the same bits as
    each view's system formed and added in view order."""
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


def _in_turn(make):
    """``make()`` with :func:`framework.threads.run_threads` running its tasks in turn."""
    import framework.threads as threads
    with pytest.MonkeyPatch.context() as m:
        m.setattr(threads, "run_threads", lambda tasks: [task() for task in tasks])
        return make()


def _lens_views(seed: int, halves: bool = True) -> list:
    """Views through two lenses (an estimated falloff each, views 0 and 2 share one), their
    coefficients expanded with the products of the terms kept, over ρ and the lenses' six
    parameters."""
    from methods.symbolic.survey.vignetting import estimate_terms, term_products, with_factors
    rng = np.random.default_rng(seed)
    views = []
    for v, lens in enumerate((0, 1, 0)):
        n = 40
        block = _block(rng, n, LENS_CODES)
        if not halves:
            block = ViewCoefficients(block.a, None, 0.5, block.codes)
        r = rng.uniform(0, 1.2, n)
        c0, *ci = estimate_terms(r)
        terms = [(c0, None)] + [(c, BASIS.n_params + 3 * lens + i) for i, c in enumerate(ci)]
        coeffs = with_factors(block, terms, n_params=9, max_degree=2, products=term_products(r))
        views.append((coeffs, rng.uniform(0, 1, (n, C)), rng.uniform(0, 1, n) if v else None))
    return views


def _recoded(views) -> list:
    """The views' expanded coefficients alone (no factors): summed as any other coefficients."""
    import dataclasses
    return [(dataclasses.replace(c, factors=None), y, w) for c, y, w in views]


@pytest.mark.parametrize("halves", [True, False])
def test_lens_gram_from_the_factors_is_the_expanded_one(halves):
    """A lens's Gram matrix from the seven products ``Γᵀ diag(w r^{2k}) Γ``, summed over the views
    of each lens and expanded once: the Gram matrix of the expanded coefficients (sparse, view by
    view) to 1e-12 of its largest entry, with and without halves; the same bits in turn."""
    views = _lens_views(3, halves)
    assert all(c.factors is not None for c, _, _ in views)
    factored = summed_views(views)
    _close(factored, reduce(operator.iadd, (weighted_system(*v) for v in _recoded(views))))
    _same_bits(factored, _in_turn(lambda: summed_views(views)))


def test_lens_gram_sparse_above_the_bound_or_from_the_cache(monkeypatch):
    """Above the bound on the dense sum's bytes, or with a view whose blocks wait in the cache
    (read when iterated: not read twice), the views are summed sparse from the expanded
    coefficients: the same bits as each view's system added in turn."""
    views = _lens_views(4)
    expected = reduce(operator.iadd, (weighted_system(*v) for v in views))
    with monkeypatch.context() as m:
        m.setattr(view_systems, "DENSE_SYSTEM_BYTES", 0)
        _same_bits(summed_views(views), expected)
    coeffs, y, w = views[1]
    lazy = TiledCoefficients([0], [lambda: coeffs], coeffs.n_rows)
    assert not lazy.held and coeffs.held
    _same_bits(summed_views([views[0], (lazy, y, w), views[2]]), expected)


def test_row_factors_errors():
    """Products the terms do not give, and products of the wrong shape, are refused."""
    from methods.symbolic.survey.vignetting import estimate_terms, term_products, with_factors
    rng = np.random.default_rng(0)
    block = _block(rng, 10, LENS_CODES)
    r = rng.uniform(0, 1, 10)
    c0, c1, c2, c3 = estimate_terms(r)
    terms = [(c0, None), (c1, 3), (c2, 4), (c3, 5)]
    basis, alpha = term_products(r)
    wrong = alpha.copy()
    wrong[0, 0, 1] += 0.1
    with pytest.raises(ValueError, match="products differ"):
        with_factors(block, terms, n_params=9, max_degree=2, products=(basis, wrong))
    with pytest.raises(ValueError, match="do not fit"):
        with_factors(block, terms, n_params=9, max_degree=2, products=(basis[:, :5], alpha))
    with pytest.raises(ValueError, match="do not fit"):
        with_factors(block, terms[:3], n_params=9, max_degree=2, products=(basis, alpha))
    lopsided = alpha.copy()
    lopsided[0, 1], lopsided[1, 0] = alpha[0, 1] + alpha[1, 0], 0.0
    with pytest.raises(ValueError, match="symmetric"):
        with_factors(block, terms, n_params=9, max_degree=2, products=(basis, lopsided))


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
