"""End-to-end inversions on bundled scenes (issue: symbolic inversion; baselines).

Observations use ``observe.max_depth=4`` so that they hold the same N_max = 3 reflections as
the inversions' own rendering: the tolerances below then measure estimator noise and
ill-posedness, not the truncation of longer paths (see README).
"""
from __future__ import annotations

import numpy as np
import pytest
from factory import make_tiny_scene, mean_difference, small_copy

from framework.config import RunSettings, compose
from framework.experiment import run_experiment

#: observations holding N_max = 3 reflections, like the paper's model: the tests of the paper's
#: estimator (``method=symbolic_paper``) and the baselines render the same light (no tail)
MATCHED = ["observe.max_depth=4", "report=false", "render.tail_bounces=0"]


def _run(tmp_path, name, overrides, base=MATCHED):
    cfg = compose([f"cache.dir={tmp_path / 'cache'}", *base, *overrides])
    return run_experiment(cfg, tmp_path / name)


def _errors(results, segments=None):
    return np.array([abs(e) for p in results["parameters"] if p["error"] is not None
                     and (segments is None or p["segment"] in segments) for e in p["error"]])


@pytest.fixture(scope="module")
def small_canyon(tmp_path_factory):
    """urban_canyon at 48x48: two street views (lit and shaded facade) and the aerial view."""
    return small_copy("urban_canyon", tmp_path_factory.mktemp("uc") / "urban_canyon", size=48,
                      views=["street_002.png", "street_003.png", "aerial_000.png"])


@pytest.mark.slow
def test_symbolic_recovers_cornell_box(tmp_path):
    """64x64, 64 spp, 512-spp observations: max |error| 0.020 at this seed; over seeds 0-5 it
    ranged 0.002-0.023 with mean errors within ±0.003 (no bias), hence the tolerance 0.03.
    Regression values (this seed) are stored to 1e-4."""
    r = _run(tmp_path, "a", ["method=symbolic_paper", "scene=cornell_box", "render.spp=64", "observe.spp=512"])
    assert r["renders"] == 1
    assert _errors(r).max() < 0.03
    white = next(p for p in r["parameters"] if p["segment"] == "white")
    np.testing.assert_allclose(white["estimate"], [0.9024, 0.7173, 0.6863], atol=2e-4)
    again = _run(tmp_path, "b", ["method=symbolic_paper", "scene=cornell_box", "render.spp=64", "observe.spp=512",
                                 f"cache.dir={tmp_path / 'other-cache'}"])
    assert [p["estimate"] for p in again["parameters"]] == [p["estimate"] for p in r["parameters"]]


@pytest.mark.slow
def test_symbolic_recovers_small_urban_canyon(tmp_path, small_canyon):
    """Kernel setting (diffuse + specular, 12 parameters), 3 views of 48x48, 64 spp.

    Max |error| measured over seeds 0-5, with ``observe.seed`` = seed and with it fixed at 0
    (12 runs; seed 0 in brackets), and the tolerances (1.5x the worst run):
    the diffuse weights of wall, roof, asphalt and balcony 0.008-0.031 [0.008] (worst roof ρ_d,
    then balcony ρ_d 0.022): 0.045; the window's specular weight 0.007-0.039 [0.039]: 0.06;
    every parameter but the roof's ρ_s 0.020-0.098 [0.039] (worst awning ρ_s): 0.15. The roof,
    seen by the aerial view only, has an ill-posed ρ_d/ρ_s split (see the tests below): its ρ_s
    (reference 0) was 0.0 [0.0] at seeds 0 and 4 but 0.11-0.40 at the others: 0.6.
    """
    r = _run(tmp_path, "k", ["method=symbolic_paper", f"scene.dir={small_canyon}", "views=all", "render.spp=64",
                             "observe.spp=512"])
    big = [p for p in r["parameters"] if p["kernel"] == "diffuse" and p["segment"] in ("wall", "roof", "asphalt", "balcony")]
    assert max(abs(e) for p in big for e in p["error"]) < 0.045
    window_s = next(p for p in r["parameters"] if p["segment"] == "window" and p["kernel"] == "specular")
    assert max(abs(e) for e in window_s["error"]) < 0.06
    roof_s = [p for p in r["parameters"] if p["segment"] == "roof" and p["kernel"] == "specular"]
    others = [p for p in r["parameters"] if p not in roof_s]
    assert len(roof_s) == 1 and len(others) == 11
    assert max(abs(e) for p in others for e in p["error"]) < 0.15
    assert max(abs(e) for e in roof_s[0]["error"]) < 0.6


@pytest.mark.slow
def test_lambertian_prior_on_small_urban_canyon(tmp_path, small_canyon):
    """The paper's Table 1 setting: segments without a specular part are recovered (max |error|
    measured over seeds 0-5, ``seed`` and ``observe.seed``: 0.005-0.012, seed 0: 0.009;
    tolerance 0.02 = 1.7x the worst seed); the window, 0.72 specular, is not (the paper's -0.67;
    measured 0.51-0.52 over the same seeds, asserted > 0.1)."""
    r = _run(tmp_path, "l", ["method=lambertian_prior", f"scene.dir={small_canyon}", "views=all",
                             "render.spp=64", "observe.spp=512"])
    assert all(p["kernel"] == "diffuse" for p in r["parameters"])
    assert _errors(r, {"roof", "balcony", "asphalt"}).max() < 0.02
    assert _errors(r, {"window"}).max() > 0.1


@pytest.mark.slow
def test_observations_rendered_once_and_cache_rebuilt_when_corrupt(tmp_path):
    """A second run reuses the observed images and the polynomial pass; a corrupt cache entry
    is detected (checksum) and rebuilt, never trusted. One pass (``method.refine=0``), so that
    the corrupted entry is one of the pass the results report."""
    scene = make_tiny_scene(tmp_path / "tiny")
    args = ["method=symbolic", f"scene.dir={scene}", "render.spp=8", "observe.spp=32", "method.refine=0"]
    first = _run(tmp_path, "1", args)
    assert first["timings_s"]["observe"] > 0 and first["views_from_cache"] == []
    second = _run(tmp_path, "2", args)
    assert second["timings_s"]["observe"] == 0.0
    assert second["views_from_cache"] == ["view_0.png", "view_1.png"]
    entries = sorted((tmp_path / "cache" / "polynomial_pass").glob("*.npz"))
    data = bytearray(entries[0].read_bytes())
    data[len(data) // 2] ^= 0xFF
    entries[0].write_bytes(bytes(data))
    third = _run(tmp_path, "3", args)
    assert len(third["views_from_cache"]) == 1
    assert [p["estimate"] for p in third["parameters"]] == [p["estimate"] for p in first["parameters"]]


@pytest.mark.slow
@pytest.mark.parametrize("method,extra,tol", [
    ("iterative", ["method.noise=fixed", "budget.renders=120"], 0.1),
    ("differentiable", ["budget.renders=120", "render.spp=16", "method.lr=0.05"], 0.035),
    ("lambertian_prior", [], 0.04),
])
def test_baselines_recover_cornell_box(tmp_path, method, extra, tol):
    """Each baseline within its own tolerance (iterative: forward differences of step 0.02
    shift the optimum by ~step/2, plus the fixed 32-spp noise; differentiable: Adam noise),
    within its render budget. Max |error| measured (``seed`` = ``observe.seed`` = s unless
    stated; the test runs seed 0, where the errors are 0.021, 0.017 and 0.006):
    iterative, seeds 0-9 and seeds 1-5 with observe.seed 0 (15 runs): 0.014-0.067 (seed 4),
    tolerance 0.1 = 1.5x; differentiable (lr 0.05, pinned: the measured setting, not the default 0.1), seeds 0-5:
    0.011-0.026, tolerance 0.035 = 1.3x;
    lambertian_prior, seeds 0-19: 0.004-0.028 (seed 7), tolerance 0.04 = 1.5x."""
    r = _run(tmp_path, method, [f"method={method}", "scene=cornell_box", "render.spp=32", "observe.spp=256",
                                *extra])
    assert r["renders"] <= 120
    assert _errors(r).max() < tol, _errors(r)


@pytest.mark.slow
def test_iterative_fresh_noise_spreads_more_than_symbolic(tmp_path):
    """The paper's claim (section 4.2): re-rendering with fresh noise at every evaluation makes
    the plain algorithm's estimates spread across seeds more than the symbolic method's.
    3 seeds on the tiny diffuse scene at 4 spp; asserted as a ratio of standard deviations > 1.5.
    Measured on 5 disjoint seed triples (0-2, 3-5, ..., 12-14, with observe.seed 0-4): ratios
    1.8-12.3 (seeds 0-2: 11.1); the claim's threshold 1.5 stays below the worst triple."""
    scene = make_tiny_scene(tmp_path / "tiny", kernels=("diffuse",))
    spread = {}
    for method, extra in (("iterative", ["method.noise=fresh", "budget.renders=40"]), ("symbolic", [])):
        runs = [_run(tmp_path, f"{method}{s}", [f"method={method}", f"scene.dir={scene}", f"seed={s}",
                                               "render.spp=4", "observe.spp=256", *extra]) for s in range(3)]
        est = np.array([[p["estimate"] for p in r["parameters"]] for r in runs])
        spread[method] = est.std(axis=0).mean()
    assert spread["iterative"] > 1.5 * spread["symbolic"], spread


@pytest.mark.slow
def test_lambertian_prior_init_is_no_worse_than_flat_guess(tmp_path, small_canyon):
    """method.init=lambertian_prior gives the kernel inversion at least the accuracy of a flat
    0.5 guess, averaged over seeds 0-3 (one seed is decided by the roof's ill-posed ρ_d/ρ_s
    split: its error is 0.02-0.5 either way), in no more solver evaluations from that guess (the
    seeded random starts do not depend on it) up to twice the standard error of the seeds'
    paired differences: since the SQP keeps its Hessian through linearly converging steps, the
    evaluations (cheap: the Hessians are the work) vary much more from seed to seed. Measured:
    evaluations flat 47 / 39 / 51 / 72, prior 50 / 93 / 43 / 54 (differences' mean 7.8,
    standard error 16.0; before that SQP change 157 vs 162)."""
    base = ["method=symbolic_paper", f"scene.dir={small_canyon}", "views=all", "render.spp=64", "observe.spp=256"]
    err, evals = {"flat": [], "prior": []}, {"flat": [], "prior": []}
    for seed in range(4):
        for name, extra in (("flat", []), ("prior", ["method.init=lambertian_prior"])):
            r = _run(tmp_path, f"{name}{seed}", [*base, f"seed={seed}", *extra])
            assert r["renders"] == (2 if name == "prior" else 1)
            err[name].append(_errors(r).mean())
            evals[name].append(r["solver_evaluations_from_guess"])
    assert np.mean(err["prior"]) <= np.mean(err["flat"])
    diff = np.subtract(evals["prior"], evals["flat"])
    assert diff.mean() <= 2.0 * diff.std(ddof=1) / np.sqrt(len(diff)), evals


@pytest.mark.slow
def test_tail_and_refine_remove_the_truncation_bias(tmp_path, small_canyon):
    """Unbounded observations (all reflections): the paper's N_max = 3 truncation biases the
    facade weights (``method=symbolic_paper``); the default ``method=symbolic`` (light beyond
    N_max linearised at the guesses, passes repeated at the estimate until it settles, 2-4
    renders) reduces it. Seeds 0-3 at 48x48, 3 views, mean |error| over the facade parameters:
    measured 0.023 without, 0.014 with tail 4 and one refinement (worst 0.08-0.105 without,
    0.034-0.103 with: at this size the noise of the small segments is comparable). Asserted on
    the mean over seeds: the default's within 0.02 (measured 0.014), and every default run used
    its tail and refined. The roof, seen by the aerial view only, is left out: its ρ_d/ρ_s split
    is ill-posed (errors up to 0.5 either way)."""
    base = [f"scene.dir={small_canyon}", "views=all", "render.spp=64", "observe.spp=256", "observe.max_depth=-1"]
    facade = {"wall", "window", "balcony", "awning", "asphalt"}
    plain, tail = [], []
    for seed in range(4):
        p = _run(tmp_path, f"plain{seed}", ["method=symbolic_paper", *base, f"seed={seed}"], base=["report=false"])
        t = _run(tmp_path, f"tail{seed}", ["method=symbolic", *base, f"seed={seed}"], base=["report=false"])
        assert p["renders"] == 1 and 2 <= t["renders"] <= 4 and t["settings"]["tail_bounces"] == 4
        plain.append(_errors(p, facade).mean())
        tail.append(_errors(t, facade).mean())
    assert np.mean(tail) <= 0.02, (tail, plain)


@pytest.mark.slow
def test_polynomial_matches_path_on_small_urban_canyon(small_canyon):
    """The polynomial at random ρ (far from its guesses, 0.5) equals Mitsuba's ``path`` image
    (max_depth = N_max + 1, box filter) at that ρ: per-segment means of 4 independent
    polynomial passes vs 4 path renders (32 spp each) agree within 4 standard errors."""

    from framework.cache import Cache
    from framework.registry import Problem
    from framework.render.mitsuba_scene import MitsubaScene
    from framework.scene import load_scene
    from methods.symbolic.system.basis import MonomialBasis
    from methods.symbolic.system.polynomial_pass import polynomial_pass

    scene = load_scene(small_canyon)
    cams = [scene.camera("street_002.png"), scene.camera("aerial_000.png")]
    params = scene.parameters()
    rho = np.random.default_rng(7).uniform(0.0, 0.45, (len(params), 3))
    ms = MitsubaScene(scene, cams, spp=32, integrator={"type": "path", "max_depth": 4})
    ms.set_weights(rho, params)
    problem = Problem(scene=scene, cameras=cams, observed={c.name: np.zeros((48, 48, 3), np.float32) for c in cams},
                      parameters=params, settings=RunSettings(variant="llvm_ad_rgb"))
    for v, cam in enumerate(cams):
        seg = ms.segment_map(v)
        path = [ms.render(v, spp=32, seed=2 * k + 1) for k in range(4)]
        poly = []
        for k in range(4):
            passed = polynomial_pass(problem, params, np.full_like(rho, 0.5), 3, spp=32, seed=100 + k,
                                     prob_floor=0.1, memory_mb=64, cache=Cache(None))
            basis = MonomialBasis(len(params), 3, passed.system.codes)
            mu = np.stack([basis.evaluate(rho[:, c]) for c in range(3)])
            poly.append(passed.image(cam.name, mu, (48, 48)))
        for s in np.unique(seg):
            a = np.array([img[seg == s].mean(axis=0) for img in path])
            b = np.array([img[seg == s].mean(axis=0) for img in poly])
            diff, se = mean_difference(a, b)
            assert np.all(np.abs(diff) <= 4 * se + 1e-5), (cam.name, s, a.mean(0), b.mean(0), se)


@pytest.mark.parametrize("key, value", [
    ("prob_floor", 1.5), ("gram", "dense"), ("psd", "maybe"), ("memory_mb", 0), ("refine", 9), ("refine", 1.5),
    ("solver.starts", 0), ("solver.algorithm", "LD_LBFGS"), ("solver.max_eval", 0), ("solver.xtol_rel", -1.0),
    ("solver.ftol_rel", -1e-3), ("solver.precondition", "maybe"),
])
def test_symbolic_errors(key, value):
    """Each bad symbolic option raises ConfigError naming it (before any rendering)."""
    from framework.errors import ConfigError
    from framework.registry import get_method
    cfg = compose(["method=symbolic", f"method.{key}={value}"])
    with pytest.raises(ConfigError, match=f"method.{key}={value}"):
        get_method("symbolic")(cfg.method)


def test_tail_bounces_range():
    from framework.errors import ConfigError
    cfg = compose(["render.tail_bounces=-1"])
    with pytest.raises(ConfigError, match=r"render.tail_bounces=-1 is out of range: use an integer \[0, 16\]"):
        RunSettings.from_config(cfg)


def test_refinement_move_ignores_weights_without_std():
    """The refinement's stopping measure, by hand: a weight moving 0.02 with std 0.005, alone
    (z_1 = Φ⁻¹(0.975) = 1.959964, scipy), moves 0.02 / (0.005 + √2 z_1 0.005) units; a weight
    without a finite std (the data do not pin it) wandering 0 -> 0.7 does not count, nor does one
    not estimated in both passes. The Šidák bound by hand: n = 12 -> Φ⁻¹(0.5 + 0.5 · 0.95^(1/12))
    = Φ⁻¹(0.997865) = 2.858; n = 384 -> 3.82."""
    from methods.symbolic.loop.refinement import moved as _moved
    previous = np.array([[0.10, 0.0, np.nan]])
    current = np.array([[0.12, 0.7, 0.3]])
    # one weight compared: 0.02 / (0.005 + √2 · 1.959964 · 0.005) = 0.02 / 0.0188590 = 1.06050
    assert _moved(previous, current, np.array([[0.005, np.nan, 0.01]]), 0.005) == pytest.approx(1.06050, rel=1e-5)
    assert _moved(previous, current, np.array([[np.nan, np.nan, 0.01]]), 0.005) == 0.0
    from methods.symbolic.loop.refinement import noise_bound
    assert noise_bound(1) == pytest.approx(1.959964, rel=1e-6)
    assert noise_bound(12) == pytest.approx(2.858, abs=1e-3) and noise_bound(384) == pytest.approx(3.820, abs=1e-3)
