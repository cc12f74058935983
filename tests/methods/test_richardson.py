"""``method.bias=richardson`` (methods/symbolic/loop/richardson.py): the pass's quarters paired into two
passes of half the spp, and the estimate extrapolated to 2ρ̂_n - ρ̂_{n/2}."""
import numpy as np
import pytest
import scipy.sparse as sp
from factory import make_problem, make_tiny_scene, method_config

from framework.errors import ConfigError
from framework.registry import get_method
from methods.symbolic.fit.fit import Fit
from methods.symbolic.loop.richardson import extrapolated
from methods.symbolic.options import SymbolicOptions
from methods.symbolic.system.coefficients import PassResult, TiledCoefficients, ViewCoefficients
from methods.symbolic.system.pass_cache import _pack, _unpack
from methods.symbolic.system.view_systems import weighted_system


def _fit(estimate) -> Fit:
    estimate = np.asarray(estimate, float)
    return Fit(estimate=estimate, std=np.full_like(estimate, 0.01), observable=np.isfinite(estimate).all(1),
               evaluated_at=np.nan_to_num(estimate), solve=None, iterates=[], correlation={}, sigma2=None,
               std_method="sandwich", stages_s={})


def test_extrapolated_by_hand():
    """ρ̂_n = 0.5, half fits 0.60 and 0.56: β̂ = 0.58 - 0.5 = 0.08, ρ̃ = 0.5 - 0.08 = 0.42. A
    parameter a half fit did not observe (NaN) keeps ρ̂_n and gets no bias; 0.1 with halves 0.2
    and 0.02: β̂ = 0.01, ρ̃ = 0.09."""
    fit = _fit([[0.5, 0.3], [0.2, 0.1]])
    halves = {0: np.array([[0.60, 0.30], [np.nan, 0.2]]), 1: np.array([[0.56, 0.26], [0.3, 0.02]])}
    out = extrapolated(fit, lambda j: _fit(halves[j]))
    np.testing.assert_allclose(out.estimate, [[0.42, 0.32], [0.2, 0.09]], atol=1e-15)
    np.testing.assert_allclose(out.spp_bias, [[0.08, -0.02], [np.nan, 0.01]], atol=1e-15)
    np.testing.assert_array_equal(out.evaluated_at, fit.evaluated_at)   # the reconstructions: as solved
    np.testing.assert_array_equal(out.std, fit.std)        # first order: the same noise (module docstring)


def test_a_weight_on_its_bound_is_not_extrapolated():
    """ρ̂_n = 0 (the box's bound) with half fits 0.12 and 0.10: no 1/n expansion holds there, so
    the estimate stays 0 and the bias is NaN; a weight off the bound (0.3 -> halves 0.34, 0.30)
    is extrapolated (0.3 - 0.02 = 0.28)."""
    fit = _fit([[0.0, 0.3]])
    halves = {0: np.array([[0.12, 0.34]]), 1: np.array([[0.10, 0.30]])}
    out = extrapolated(fit, lambda j: _fit(halves[j]))
    np.testing.assert_allclose(out.estimate, [[0.0, 0.28]], atol=1e-15)
    assert np.isnan(out.spp_bias[0, 0]) and out.spp_bias[0, 1] == pytest.approx(0.02)


def test_a_segment_whose_bound_differs_between_fits_is_not_extrapolated():
    """Segment {0, 1} (a diffuse and a mirror weight), two channels. Channel 0: the mirror weight
    is on its bound in the whole fit (0) and off it in a half (0.12), so the diffuse weight it
    traded with (0.5 -> halves 0.46, 0.50) is not extrapolated either. Channel 1: all three fits
    have the mirror weight on the bound: the diffuse weight is (0.4 -> 0.42, 0.40: 0.39).
    Parameter 2, its own segment, is extrapolated in both channels."""
    fit = _fit([[0.5, 0.4], [0.0, 0.0], [0.3, 0.3]])
    halves = {0: np.array([[0.46, 0.42], [0.12, 0.0], [0.34, 0.34]]),
              1: np.array([[0.50, 0.40], [0.0, 0.0], [0.30, 0.30]])}
    out = extrapolated(fit, lambda j: _fit(halves[j]), segments=[[0, 1], [2]])
    np.testing.assert_allclose(out.estimate, [[0.5, 0.39], [0.0, 0.0], [0.28, 0.28]], atol=1e-15)
    assert np.isnan(out.spp_bias[:2, 0]).all() and np.isnan(out.spp_bias[1, 1])
    assert out.spp_bias[0, 1] == pytest.approx(0.01)


def test_an_extrapolation_out_of_the_feasible_set_is_not_applied():
    """Segment {0, 1}, three channels. Channel 0: the mirror weight 0.01 with half fits 0.05, 0.05
    would become 0.01 - 0.04 = -0.03 (was: applied, a negative weight); the segment keeps its
    weights as solved. Channel 1: the sum 0.6 + 0.39 would become 0.58 + 0.43 = 1.01 > 1: kept.
    Channel 2: feasible (0.5 -> 0.48, 0.2 -> 0.19), corrected. Parameter 2 is on its bound and
    parameter 3 was not observed by a half: the correction says so for each weight."""
    fit = _fit([[0.5, 0.6, 0.5], [0.01, 0.39, 0.2], [0.0, 0.0, 0.0], [0.3, 0.3, 0.3]])
    halves = {0: np.array([[0.5, 0.62, 0.52], [0.05, 0.35, 0.21], [0.1, 0.1, 0.1], [np.nan, 0.3, 0.3]]),
              1: np.array([[0.5, 0.62, 0.52], [0.05, 0.35, 0.21], [0.1, 0.1, 0.1], [0.3, 0.3, 0.3]])}
    out = extrapolated(fit, lambda j: _fit(halves[j]), segments=[[0, 1], [2], [3]])
    np.testing.assert_allclose(out.estimate[:2], [[0.5, 0.6, 0.48], [0.01, 0.39, 0.19]], atol=1e-12)
    assert np.all(out.estimate[:2] >= 0) and np.all(out.estimate[:2].sum(axis=0) <= 1)
    assert out.spp_bias_actions.tolist() == [["infeasible", "infeasible", "corrected"],
                                             ["infeasible", "infeasible", "corrected"],
                                             ["on its bound"] * 3,
                                             ["not observed", "corrected", "corrected"]]
    assert np.isnan(out.spp_bias[:3, :2]).all() and out.spp_bias[0, 2] == pytest.approx(0.02)


def _quarters(rng, n=40, m=6, C=2):
    """Random sparse quarter-sample coefficients ``q1..q4`` (C channels) and the block kept from them."""
    q = [[sp.random(n, m, density=0.4, random_state=rng, format="csr") for _ in range(C)] for _ in range(4)]
    half = lambda x, y: [0.5 * (u + v) for u, v in zip(x, y)]  # noqa: E731
    block = ViewCoefficients(half(q[0], q[1]), half(q[2], q[3]), 0.5, np.arange(m, dtype=np.int64), q[0], q[2])
    return q, block


def test_halved_pairs_the_quarters():
    """halved(0) is the pass (q1, q2), halved(1) the pass (q3, q4), and the halved pass's Gram
    system is that of those halves, summed over the views as the pass sums them; without the
    system (the field path) the halved pass has the same codes."""
    rng = np.random.default_rng(0)
    q, block = _quarters(rng)
    for j, (first, second) in enumerate(((q[0], q[1]), (q[2], q[3]))):
        half = block.halved(j)
        for c in range(2):
            assert abs(half.a[c] - first[c]).max() == 0
            assert abs(half.b[c] - second[c]).max() < 1e-15
    y = rng.uniform(size=(40, 2))
    views = {"v0": TiledCoefficients([0, 25], [block_rows(block, 0, 25), block_rows(block, 25, 40)], 40)}
    result = PassResult(weighted_system(views["v0"], y, None), views)
    halved = result.halved(1, {"v0": y.reshape(5, 8, 2)})
    expected = weighted_system(ViewCoefficients(q[2], q[3], 0.5, block.codes), y, None)
    for got, want in zip(halved.system.G, expected.G):
        assert abs(got - want).max() < 1e-12
    np.testing.assert_allclose(halved.system.b, expected.b, atol=1e-12)
    lean = result.halved(1, {"v0": y.reshape(5, 8, 2)}, system=False)     # the field path's: no system
    assert lean.system is None
    np.testing.assert_array_equal(lean.codes, halved.codes)


def block_rows(block: ViewCoefficients, lo: int, hi: int) -> ViewCoefficients:
    rows = lambda mats: [m[lo:hi] for m in mats]  # noqa: E731
    return ViewCoefficients(rows(block.a), rows(block.b), block.split, block.codes, rows(block.a1), rows(block.b1))


def test_quarters_survive_the_cache():
    """A tile's quarters are packed with it and read back (the cache serves refits too)."""
    _, block = _quarters(np.random.default_rng(1))
    back = _unpack(_pack(block), 2)
    for mine, theirs in ((block.a1, back.a1), (block.b1, back.b1), (block.a, back.a)):
        for x, y in zip(mine, theirs):
            assert abs(x - y).max() == 0
    plain = _unpack(_pack(ViewCoefficients(block.a, block.b, 0.5, block.codes)), 2)
    assert plain.a1 is None and plain.b1 is None


def test_richardson_errors(tmp_path):
    with pytest.raises(ConfigError, match="method.bias=richardson refits the pass's quarters through the cross Gram"):
        SymbolicOptions(**{**_shipped(), "gram": "plain", "bias": "richardson"})
    with pytest.raises(ValueError, match="no quarters: render with method.bias=richardson"):
        ViewCoefficients([sp.csr_matrix((2, 1))], [sp.csr_matrix((2, 1))]).halved(0)
    root = make_tiny_scene(tmp_path / "scene", size=8)
    problem = make_problem(root, None, "render.spp=6", f"cache.dir={tmp_path / 'cache'}")
    method = get_method("symbolic")(method_config("symbolic", bias="richardson"))
    with pytest.raises(ConfigError, match="render.spp=6: method.bias=richardson splits each pixel's samples"):
        method.check_problem(problem)


def _shipped() -> dict:
    from framework.options import build
    return vars(build(SymbolicOptions, method_config("symbolic"), section="method"))


def test_richardson_run_extrapolates_the_plain_estimate(tmp_path):
    """On the tiny scene (2 views of 16x16, one pass of 16 spp): the pass with quarters keeps the
    plain pass's halves bit for bit (test_quarters_split_each_half), so the plain run's estimate is
    the Richardson run's plus the bias it removed, and results.json's ``spp_bias`` reports it."""
    root = make_tiny_scene(tmp_path / "scene", size=16)
    problem = make_problem(root, None, "method=symbolic_paper", "render.spp=16", f"cache.dir={tmp_path / 'cache'}")
    runs = {bias: get_method("symbolic_paper")(method_config("symbolic_paper", bias=bias)).run(problem)
            for bias in ("none", "richardson")}
    assert "spp_bias" not in runs["none"].extras
    report = runs["richardson"].extras["spp_bias"]
    assert report["method"] == "richardson" and report["spp"] == 16
    beta = np.array(report["bias"], dtype=float)
    at_bound = np.abs(runs["none"].estimate) <= 1e-9        # not extrapolated: null in spp_bias
    assert at_bound.any() and np.isnan(beta[at_bound]).all()
    # nor their segments' weights where a half fit's bounds differ (measured: 2 of 12 extrapolated)
    assert np.isfinite(beta).any() and np.abs(beta[np.isfinite(beta)]).max() > 0
    np.testing.assert_allclose(runs["richardson"].estimate + np.nan_to_num(beta), runs["none"].estimate, atol=1e-9)
    np.testing.assert_array_equal(runs["richardson"].std, runs["none"].std)
    corrected = np.array(report["correction"]) == "corrected"        # what it did, per weight
    np.testing.assert_array_equal(corrected, np.isfinite(beta))
    assert set(np.array(report["correction"])[at_bound]) == {"on its bound"}
