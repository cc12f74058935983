"""The symbolic fit of field photographs (methods/symbolic/fit/field.py): pixel weights, per-view
exposure gains and robust reweighting, all from the stored per-pixel coefficients."""
import dataclasses

import numpy as np
import pytest

from factory import run_method, run_symbolic, tiny_problem, view_systems
from framework.errors import ConfigError
from framework.scene.model import Photometry
from methods.symbolic.misfit.robust_weights import robust_weights
from methods.symbolic.survey.exposure import GAIN_MAX, with_gain
from methods.symbolic.system.coefficients import ViewCoefficients
from methods.symbolic.system.view_systems import weighted_system

GAINS = np.array([1.5, 0.8, 1.2])      # view_1's gains per channel; view_0 is the reference


@pytest.fixture(scope="module")
def problem(tmp_path_factory):
    """Two views of the tiny diffuse scene, 32 spp, observations at 256 spp."""
    return tiny_problem(tmp_path_factory.mktemp("field"), n_views=2, spp=32)


def _per_view(problem, observed=None):
    names = [c.name for c in problem.cameras]
    scene = dataclasses.replace(problem.scene, photometry=Photometry(exposure="per_view", reference_view=names[0]))
    return dataclasses.replace(problem, scene=scene, observed=observed or problem.observed)


def _scaled(problem):
    """view_1 photographed with GAINS."""
    name = problem.cameras[1].name
    return {**problem.observed, name: problem.observed[name] * GAINS}


def test_unit_weights_rebuild_the_pass_system_and_the_plain_estimate(problem):
    """With every weight 1, the system rebuilt from the coefficients is the pass's own (up to
    rounding) and the field path's estimate equals the plain path's."""
    from methods.symbolic import SymbolicMethod
    from framework.config import method_defaults
    method = SymbolicMethod(method_defaults("symbolic"))
    params = problem.parameters
    x0 = np.full((len(params), 3), 0.5)
    settings = problem.settings
    views = view_systems(problem, params, x0, max_bounces=settings.max_bounces, spp=settings.spp,
                         prob_floor=method.options.prob_floor, memory_mb=method.options.memory_mb,
                         tail_bounces=settings.tail_bounces)
    for cam, (system, coeffs) in zip(problem.cameras, views):
        rebuilt = weighted_system(coeffs, problem.observed[cam.name].reshape(-1, 3), np.ones(cam.width * cam.height))
        np.testing.assert_array_equal(rebuilt.codes, system.codes)
        for c in range(3):
            scale = abs(system.G[c]).max()
            assert abs(rebuilt.G[c] - system.G[c]).max() <= 1e-9 * scale
        np.testing.assert_allclose(rebuilt.b, system.b, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(rebuilt.yy, system.yy, rtol=1e-12)
    plain = run_symbolic(problem)
    ones = {c.name: np.ones((c.height, c.width)) for c in problem.cameras}
    # bias none: the field path would otherwise extrapolate its estimate (method.bias auto)
    field = run_symbolic(dataclasses.replace(problem, weights=ones), robust="none", bias="none")
    assert field.extras["field"]["scene_weights"] is True
    np.testing.assert_allclose(field.estimate, plain.estimate, atol=1e-6)


def test_with_gain_multiplies_every_monomial_by_the_gain():
    """A view's polynomial at (ρ, h) equals GAIN_MAX·h times its polynomial at ρ (hand-built
    coefficients over D = 2, N_max = 2: monomials 1, ρ0, ρ1, ρ0², ρ0ρ1)."""
    import scipy.sparse as sp
    from methods.symbolic.system.basis import MonomialBasis
    from methods.symbolic.trace.monomial_codes import multiset_codes
    D, N = 2, 2
    keys = np.array([0, 1, 2, 1 + 3 * 1, 1 + 3 * 2])            # ordered keys -> multiset codes
    codes = np.unique(multiset_codes(keys, D, N))
    gamma = [sp.csr_matrix(np.arange(1.0, 1 + 2 * len(codes)).reshape(2, len(codes)))]
    coeffs = ViewCoefficients(gamma, None, 0.5, codes)
    ext = with_gain(coeffs, n_params=D, max_degree=N, n_total=D + 1, gain=D)
    rho, h = np.array([0.3, 0.7]), 0.4
    before = gamma[0] @ MonomialBasis(D, N, codes).evaluate(rho)
    basis = MonomialBasis(D + 1, N + 1, ext.codes)              # adds the constant, absent here
    after = ext.a[0] @ basis.evaluate(np.append(rho, h))[np.searchsorted(basis.codes, ext.codes)]
    np.testing.assert_allclose(after, GAIN_MAX * h * before, rtol=1e-12)


def test_per_view_gains_are_estimated_with_their_std(problem):
    """view_1 scaled by GAINS: the gains come back within 4 std (std from the sandwich) and
    within 3 %, and ρ within 0.02 of the fit of the unscaled photographs (measured 0.009)."""
    clean = run_symbolic(problem, robust="none")
    result = run_symbolic(_per_view(problem, _scaled(problem)), robust="none")
    exposure = {e["view"]: e for e in result.extras["exposure"]}
    ref, other = (exposure[c.name] for c in problem.cameras)
    assert ref["reference"] and ref["estimate"] == [1.0, 1.0, 1.0] and ref["std"] is None
    est, std = np.array(other["estimate"]), np.array(other["std"])
    assert (std > 0).all() and (std < 0.05).all()
    assert (np.abs(est - GAINS) < 4 * std).all(), (est, std)
    assert (np.abs(est / GAINS - 1) < 0.03).all()
    assert np.nanmax(np.abs(result.estimate - clean.estimate)) < 0.02
    # the reconstruction of view_1 is in view_1's exposure
    rec = result.reconstructions[problem.cameras[1].name]
    assert abs(rec.mean() / _scaled(problem)[problem.cameras[1].name].mean() - 1) < 0.05


@pytest.mark.slow
def test_robust_weights_ignore_an_object_the_model_lacks(problem):
    """A bright 4x4 blob (a 'car') in view_0: the Cauchy fit stays within two standard errors of
    the Cauchy fit of the clean photographs and gives the blob weights < 0.05; the plain L2 fit
    is dragged by more than 0.3."""
    name = problem.cameras[0].name
    blob = problem.observed[name].copy()
    blob[7:11, 6:10] = 3.0 * blob.max()
    dirty = dataclasses.replace(problem, observed={**problem.observed, name: blob})
    clean = run_symbolic(problem, robust="none")
    clean_robust = run_symbolic(problem, robust="cauchy")
    l2 = run_symbolic(dirty, robust="none")
    robust = run_symbolic(dirty, robust="cauchy")
    assert np.nanmax(np.abs(l2.estimate - clean.estimate)) > 0.3             # measured 0.62
    # measured 0.0098; the clean fits' std is ~0.01 (the robust and L2 clean fits differ by 0.015)
    assert np.nanmax(np.abs(robust.estimate - clean_robust.estimate)) < 2 * np.nanmax(clean_robust.std)
    weights = robust.pixel_weights[name]
    assert weights[7:11, 6:10].max() < 0.05 and np.median(weights) > 0.8
    assert robust.extras["field"]["robust"] == "cauchy"


def test_robust_weights_by_hand():
    """Cauchy weight 1/(1 + (t/2.385)²) of t = |r|/(MAD / 0.67449), the MAD's Gaussian scale
    (0.67449 = the median of |N(0, 1)|); Huber min(1, 1.345/t); with each pixel's own variance
    v_p the scale s solves median(|r - median r| / sqrt(s² + v)) = 0.67449 and t = |r|/sqrt(s² + v)."""
    r = np.array([[-1.0], [0.0], [1.0], [2.0], [40.0]])
    used = np.ones(5, bool)
    scale = 1.0 / 0.6744897501960817       # median 1, |r - 1| = 2, 1, 0, 1, 39: MAD 1
    t = np.abs(r[:, 0]) / scale
    np.testing.assert_allclose(robust_weights(r, used, loss="cauchy"), 1 / (1 + (t / 2.385) ** 2))
    np.testing.assert_allclose(robust_weights(r, used, loss="huber"), np.minimum(1, 1.345 / np.maximum(t, 1e-300)))
    np.testing.assert_allclose(robust_weights(r, used, loss="cauchy", floor=10.0), 1 / (1 + (np.abs(r[:, 0]) / 10 / 2.385) ** 2))
    # v = 1 everywhere: s² + 1 = (MAD / 0.67449)², so the weights are those without v
    v = np.full((5, 1), 1.0)
    assert (1.0 / 0.6744897501960817) ** 2 > 1.0
    np.testing.assert_allclose(robust_weights(r, used, loss="cauchy", variance=v),
                               1 / (1 + (t / 2.385) ** 2), rtol=1e-9)


def test_masked_pixels_do_not_count(problem):
    """Pixels of weight 0 may hold anything: the estimate is the one without them."""
    name = problem.cameras[0].name
    weights = {c.name: np.ones((c.height, c.width)) for c in problem.cameras}
    weights[name][:8] = 0.0
    garbage = problem.observed[name].copy()
    garbage[:8] = 5.0
    masked = dataclasses.replace(problem, weights=weights)
    a = run_symbolic(masked, robust="none")
    b = run_symbolic(dataclasses.replace(masked, observed={**problem.observed, name: garbage}), robust="none")
    np.testing.assert_allclose(a.estimate, b.estimate, atol=1e-9)


def test_field_errors(problem):
    """Baselines refuse per-view exposure; a reference view outside the run's views is refused."""
    per_view = _per_view(problem)
    for name in ("iterative", "differentiable"):
        with pytest.raises(ConfigError, match=f"method={name} does not estimate per-view exposure"):
            run_method(name, per_view)
    only_other = dataclasses.replace(per_view, cameras=per_view.cameras[1:])
    with pytest.raises(ConfigError, match="reference_view .* is not among this run's views"):
        run_symbolic(only_other)
    with pytest.raises(ConfigError, match="method.robust=bisquare"):
        run_symbolic(problem, robust="bisquare")


@pytest.mark.slow
@pytest.mark.parametrize("method", ["iterative", "differentiable"])
def test_baselines_ignore_masked_pixels(problem, method):
    """A baseline's cost leaves weight-0 pixels out (its first cost equal with and without
    garbage there, same seeds)."""
    name = problem.cameras[0].name
    weights = {c.name: np.ones((c.height, c.width)) for c in problem.cameras}
    weights[name][:8] = 0.0
    garbage = problem.observed[name].copy()
    garbage[:8] = 5.0
    masked = dataclasses.replace(problem, weights=weights, settings=dataclasses.replace(problem.settings, budget_renders=8))
    a = run_method(method, masked)
    b = run_method(method, dataclasses.replace(masked, observed={**problem.observed, name: garbage}))
    assert a.cost_history[0] == pytest.approx(b.cost_history[0], rel=1e-6)


def test_boundary_pixels_are_left_out(problem):
    """``method.boundary=1`` gives weight 0 to the pixels next to a change of segment (here the
    block's outline against the ground and the sky) and 1 elsewhere; ``auto`` is 0 for pinhole
    cameras (nothing was resampled)."""
    from framework.render.mitsuba_scene import MitsubaScene
    result = run_symbolic(problem, boundary=1, robust="none", refine=0)
    seg = MitsubaScene(problem.scene, list(problem.cameras), spp=1).segment_map(0)
    w = result.pixel_weights[problem.cameras[0].name]
    same = np.ones(seg.shape, bool)
    same[:, 1:] &= seg[:, 1:] == seg[:, :-1]
    same[:, :-1] &= seg[:, 1:] == seg[:, :-1]
    same[1:] &= seg[1:] == seg[:-1]
    same[:-1] &= seg[1:] == seg[:-1]
    np.testing.assert_array_equal(w, same.astype(np.float32))
    assert 0 < (w == 0).mean() < 0.5
    assert "field" not in run_symbolic(problem, refine=0).extras        # auto: no resampled view


def test_solve_stages_account_for_the_whole_solve(tmp_path):
    """On the field path with registration and the bias correction, solve_stages_s names the
    field's stages, every robust round's solve, the registration and the refits, and adds up to
    timings_s.solve (``other`` is the remainder, never negative)."""
    problem = tiny_problem(tmp_path, kernels=("diffuse", "specular"), spp=8, n_views=2)
    ones = {c.name: np.ones((c.height, c.width)) for c in problem.cameras}
    out = run_symbolic(dataclasses.replace(problem, weights=ones), refine=1, align="rotation", bias="richardson")
    stages = out.extras["solve_stages_s"]
    assert {"psd", "solver", "uncertainty", "field_setup", "weighted_systems", "robust_weights",
            "registration", "bias_refits", "other"} <= set(stages)
    assert min(stages.values()) >= 0
    np.testing.assert_allclose(sum(stages.values()), out.timings_s["solve"], rtol=1e-9)
