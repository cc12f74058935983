"""The ``glossy(α)`` kernel family (GGX lobe of fixed roughness, Fresnel 1) end to end: the
registry's parsing, the polynomial integrator against Mitsuba's own ``roughconductor`` and
``path``, the differentiable baseline's gradient, and a symbolic run's parameter names.

Monte Carlo tolerances are in standard errors (SE) of the difference of two estimators' means,
from the sample variances of independent repetitions (:func:`factory.mean_difference`); the
measured z-values are stated in each test (seeds as written, llvm_ad_rgb).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from factory import ad_and_fd_gradients, edit_scene_yaml, make_problem, make_tiny_scene, mean_difference, run_symbolic

from framework import brdf_kernels as K
from framework.errors import SceneError

GLOSSY = "glossy(0.2)"


# ------------------------------------------------------------------------------------------------
# Registry
# ------------------------------------------------------------------------------------------------
def test_registry_glossy_kernel():
    """``glossy(α)``: a non-Dirac roughconductor (GGX, Fresnel 1) at weight ρ; one kernel per
    canonical name (``repr`` of the float), whatever way the number is written."""
    k = K.get("glossy(0.15)")
    assert k.name == "glossy(0.15)" and not k.delta
    assert k.weighted_bsdf(0.4) == {"type": "roughconductor", "distribution": "ggx", "alpha": 0.15,
                                    "material": "none", "specular_reflectance": 0.4}
    assert K.get("glossy(0.150)") is k and K.get("glossy(1.5e-1)") is k
    assert K.get("glossy(1)").name == "glossy(1.0)"
    assert K.canonical("glossy(0.30)") == "glossy(0.3)"
    assert "glossy(0.2)" in K.KERNELS and "glossy(2)" not in K.KERNELS and "glossy" not in K.KERNELS
    assert K.KERNELS["glossy(0.2)"] is K.get("glossy(0.2)")


@pytest.mark.parametrize("name, match", [
    ("glossy(0)", r"kernel 'glossy\(0\)'.*\(0, 1\].*e\.g\. glossy\(0\.15\)"),
    ("glossy(abc)", r"kernel 'glossy\(abc\)'.*not a number.*\(0, 1\].*e\.g\. glossy\(0\.15\)"),
    ("glossy(2)", r"kernel 'glossy\(2\)'.*\(0, 1\].*e\.g\. glossy\(0\.15\)"),
    ("glossy", r"kernel 'glossy'.*\(0, 1\].*e\.g\. glossy\(0\.15\)"),
    ("specular(0.1)", r"kernel 'specular\(0\.1\)'.*specular takes no parameter.*glossy\(0\.15\)"),
])
def test_glossy_parse_errors(name, match):
    """Each bad name is a SceneError naming the kernel, the range (0, 1] and an example."""
    with pytest.raises(SceneError, match=match):
        K.get(name)


def test_scene_loader_accepts_glossy(tmp_path):
    """scene.yaml: ``glossy(α)`` in ``kernels`` and as a ``reference`` key; a bad α is the loader's
    SceneError naming the segment."""
    from framework.scene import load_scene
    root = _glossy_scene(tmp_path / "s")
    seg = load_scene(root).segments[0]
    assert seg.kernels == ("diffuse", GLOSSY) and set(seg.reference) == {"diffuse", GLOSSY}

    def bad_alpha(d):
        d["segments"][0]["kernels"] = ["diffuse", "glossy(0)"]
        del d["segments"][0]["reference"]
    edit_scene_yaml(root, bad_alpha)
    with pytest.raises(SceneError, match=r"segment 'ground' kernels: kernel 'glossy\(0\)'"):
        load_scene(root)


def test_kernel_sum_flags():
    """The kernel sum's component of a glossy kernel is GlossyReflection (not Diffuse), on both sides."""
    import mitsuba as mi

    from framework.render import kernel_bsdf as KB
    b = mi.load_dict(KB.forward_bsdf(["diffuse", GLOSSY, "specular"], ("R", "G", "B")))
    both = mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
    want = [mi.BSDFFlags.DiffuseReflection, mi.BSDFFlags.GlossyReflection, mi.BSDFFlags.DeltaReflection]
    for i, lobe in enumerate(want):
        assert b.flags(i) == int(lobe | both)
    assert mi.has_flag(b.flags(), mi.BSDFFlags.Glossy)


# ------------------------------------------------------------------------------------------------
# (a) White furnace: the polynomial integrator's unit glossy lobe vs Mitsuba's roughconductor
# ------------------------------------------------------------------------------------------------
def _sphere_scene(bsdf: dict, res: int):
    """A unit sphere 3 m in front of a 45° camera under a constant unit environment, box filter."""
    import mitsuba as mi
    T = mi.ScalarTransform4f
    return mi.load_dict({
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 45,
                   "to_world": T().look_at(origin=[0, 0, 3], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}}},
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}},
        "sphere": {"type": "sphere", "radius": 1.0, "bsdf": bsdf},
    }, optimize=False)


def _polynomial_image(integ, scene, rho: np.ndarray, spp: int, seed: int, res: int) -> np.ndarray:
    """One pass's polynomial (``seed``) evaluated at ``rho`` (D, 3): a (res, res, 3) image."""
    from methods.symbolic.system.basis import MonomialBasis
    codes, mats = integ.coefficients_sparse(scene, spp=spp, seed=seed)
    basis = MonomialBasis(integ.n_params, integ.max_bounces)
    at = np.searchsorted(basis.codes, codes)
    img = []
    for ch, m in enumerate(mats):
        values = basis.evaluate(rho[:, ch])[at]
        img.append(m @ values)
    return np.stack(img, -1).reshape(res, res, 3)


def _z_images(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(R, res, res, 3) repetitions of two estimators: z of the difference of their image means
    and 2x2-quadrant means, per channel (SE from the repetitions' sample variances)."""
    R, res = a.shape[0], a.shape[1]
    quads = lambda x: x.reshape(R, 2, res // 2, 2, res // 2, 3).mean((2, 4)).reshape(R, -1)
    stats = lambda x: np.concatenate([x.mean((1, 2)), quads(x)], axis=1)
    diff, se = mean_difference(stats(a), stats(b))
    return diff / se


@pytest.mark.parametrize("alpha", [0.05, 0.5])
def test_white_furnace_matches_roughconductor(alpha):
    """Sphere under a constant unit sky, every incidence angle from normal to grazing: the
    polynomial integrator's coefficient of ρ_g for the unit ``glossy(α)`` kernel (N_max = 1: a
    convex sphere never sees itself), i.e. the lobe's directional albedo, plus the sky seen
    directly, equals Mitsuba ``path`` (max_depth 2) on a sphere with Mitsuba's own
    ``roughconductor`` (ggx, α, material none) -- independent of the registry's dict.

    R = 16 repetitions of each at 32x32, 16 spp; image mean and 2x2-quadrant means per channel
    agree within 5 SE. Measured max |z| (15 statistics) = 1.01 (α = 0.05) and 0.96 (α = 0.5);
    over seed offsets + 1000 k, k = 0-5: 1.0-2.3 and 0.8-1.7. Power: at α = 0.5
    the lobe loses energy to masking (directional albedo 0.69 at normal incidence, by quadrature
    of D G1 G1 / 4 cos): the image mean is 0.823 against 1 for a lossless lobe, 300 SE away, so a
    missing or doubled shadowing term, or a lost 1/q, would fail by far.
    """
    import mitsuba as mi

    from methods.symbolic.trace.integrator import PolynomialPathIntegrator
    res, spp, R = 32, 16, 16
    name = f"glossy({alpha})"
    scene = _sphere_scene({"type": "diffuse"}, res)
    integ = PolynomialPathIntegrator.create([(scene.shapes()[0], 0)], [[(name, 0)]], 1,
                                            np.ones((1, 3)), max_bounces=1)
    ref_scene = _sphere_scene({"type": "twosided", "bsdf": {"type": "roughconductor", "distribution": "ggx",
                                                           "alpha": alpha, "material": "none"}}, res)
    path = mi.load_dict({"type": "path", "max_depth": 2})
    rho = np.ones((1, 3))
    poly = np.array([_polynomial_image(integ, scene, rho, spp, 10 + r, res) for r in range(R)])
    ref = np.array([np.asarray(mi.render(ref_scene, integrator=path, spp=spp, seed=100 + r)) for r in range(R)])
    z = _z_images(poly, ref)
    assert np.all(np.abs(z) < 5), z.round(2)
    if alpha == 0.5:
        mean, se = poly.mean(), poly.mean((1, 2, 3)).std(ddof=1) / np.sqrt(R)
        assert (1 - mean) / se > 50, (mean, se)


# ------------------------------------------------------------------------------------------------
# (b) Polynomial = path on a scene with a diffuse + glossy segment and a diffuse one
# ------------------------------------------------------------------------------------------------
SEGMENTS = [[("diffuse", 0), (GLOSSY, 1)],      # 0: the ground, diffuse + glossy
            [("diffuse", 2)]]                   # 1: the block, diffuse


def _ground_and_block(rho: np.ndarray, res: int):
    """A ground quad (diffuse + glossy(0.2) kernel sum) and a box (diffuse) under a constant sky and
    a sun, forward kernel-sum BSDFs at ``rho`` (3, 3); returns the scene and its shape segments."""
    import mitsuba as mi

    from framework.render import kernel_bsdf as KB
    T = mi.ScalarTransform4f
    scene = mi.load_dict({
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 50,
                   "to_world": T().look_at(origin=[5, -4, 3], target=[0, 0, 0.6], up=[0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}}},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.3, 0.35, 0.45]}},
        "sun": {"type": "directional", "direction": [0.66, -0.53, -0.53],      # highlight in view
                "irradiance": {"type": "rgb", "value": [3.0, 2.9, 2.8]}},
        "ground": {"type": "rectangle", "to_world": T().scale([6, 6, 1]),
                   "bsdf": KB.forward_bsdf(["diffuse", GLOSSY], ("R", "G", "B"))},
        "block": {"type": "cube", "to_world": T().translate([0, 0, 1]),
                  "bsdf": KB.forward_bsdf(["diffuse"], ("R", "G", "B"))},
    }, optimize=False)
    params = mi.traverse(scene)
    for shape, kl in (("ground", SEGMENTS[0]), ("block", SEGMENTS[1])):
        for key, (_, p) in zip(KB.weight_keys(kl), kl):
            params[f"{shape}.bsdf.{key}"] = mi.Color3f(*[float(v) for v in rho[p]])
    params.update()
    seg = {"ground": 0, "block": 1}
    return scene, [(s, seg[s.id()]) for s in scene.shapes()]


def test_polynomial_matches_path_with_glossy():
    """The polynomial (N_max = 3) evaluated at random ρ equals Mitsuba ``path`` (max_depth 4, no
    Russian roulette) on the forward kernel-sum scene at the same ρ: the sun's highlight reaches
    the camera through the glossy lobe by next-event estimation only, the sky by both strategies
    (MIS), and the block's light inter-reflects with the glossy ground.

    R = 16 repetitions of each at 32x32, 32 spp, independent seeds; image means and 2x2-quadrant
    means per channel agree within 4 SE (as tests/methods/test_polynomial_integrator.py, with 16
    repetitions instead of 4 so that the SE itself is well estimated). Measured max |z| = 1.36
    over the 15 statistics; over seed offsets + 1000 k, k = 0-5: 1.3-3.1. Power: the glossy
    ground is a visible part of the image: the image mean at ρ_g = 0 is lower by 0.121 (of
    0.344), 399 SE of the difference.
    """
    import mitsuba as mi

    from methods.symbolic.trace.integrator import PolynomialPathIntegrator
    rng = np.random.default_rng(11)
    rho = rng.uniform(0.15, 0.45, (3, 3))
    res, spp, R, N = 32, 32, 16, 3
    scene, shape_segments = _ground_and_block(rho, res)
    integ = PolynomialPathIntegrator.create(shape_segments, SEGMENTS, 3, np.full((3, 3), 0.4), max_bounces=N)
    path = mi.load_dict({"type": "path", "max_depth": N + 1, "rr_depth": 1000})
    poly = np.array([_polynomial_image(integ, scene, rho, spp, 10 + r, res) for r in range(R)])
    ref = np.array([np.asarray(mi.render(scene, integrator=path, spp=spp, seed=100 + r)) for r in range(R)])
    z = _z_images(poly, ref)
    assert np.all(np.abs(z) < 4), z.round(2)
    no_glossy = rho.copy()
    no_glossy[1] = 0
    dark = np.array([_polynomial_image(integ, scene, no_glossy, spp, 10 + r, res) for r in range(R)])
    diff, se = mean_difference(ref.mean((1, 2, 3)), dark.mean((1, 2, 3)))
    assert diff / se > 8, (diff, se)


# ------------------------------------------------------------------------------------------------
# (c) The differentiable baseline's gradient for a glossy weight
# ------------------------------------------------------------------------------------------------
def _glossy_scene(root: Path) -> Path:
    """make_tiny_scene with the ground [diffuse, glossy(0.2)] and the block [diffuse]."""
    root = make_tiny_scene(root, kernels=("diffuse",))

    def edit(d):
        d["segments"][0]["kernels"] = ["diffuse", GLOSSY]
        d["segments"][0]["reference"] = {"diffuse": [0.5, 0.45, 0.4], GLOSSY: [0.1, 0.15, 0.2]}
    edit_scene_yaml(root, edit)
    return root


REPEATS, SPP, STEP, RHO = 16, 64, 0.05, 0.3


@pytest.fixture(scope="module")
def glossy_gradients(tmp_path_factory):
    """``(problem, ad, fd)``: ``REPEATS`` independent AD and finite-difference estimates
    ``(REPEATS, P, C)`` of dε/dρ at ρ = 0.3 on the tiny scene with a glossy ground (one view),
    as tests/methods/test_differentiable_gradients.py: AD is the method's own pass (primal and adjoint
    at independent seeds); FD is ``2 (I_r - obs) · (I_c(ρ + h e_j) - I_c(ρ - h e_j)) / 2h``
    with common random numbers (seed ``c`` on both sides) and the residual from an independent
    seed ``r``. The expected image is a cubic in ρ (N_max = 3), so the central difference's own
    error is O(h²), below the noise at h = 0.05."""
    from framework.config import RunSettings
    from framework.observe import render_references
    from framework.registry import Problem
    from framework.scene import load_scene
    scene = load_scene(_glossy_scene(tmp_path_factory.mktemp("glossy_grad") / "s"))
    cams = list(scene.cameras)[:1]
    obs = render_references(scene, cams, spp=64, max_depth=4, seed=0)
    settings = RunSettings(spp=SPP, max_bounces=3, budget_renders=100, seed=0, cache_dir=None)
    problem = Problem(scene=scene, cameras=cams, observed={c.name: o for c, o in zip(cams, obs)},
                      parameters=scene.parameters(), settings=settings)
    return (problem,) + ad_and_fd_gradients(problem, spp=SPP, rho=RHO, repeats=REPEATS, step=STEP)


@pytest.mark.slow
def test_glossy_gradient_matches_finite_differences(glossy_gradients):
    """Every weight and channel (ground diffuse, ground glossy(0.2), block diffuse): |mean AD -
    mean FD| < 4 SE (16 repetitions each at 64 spp, 16x16; SE sqrt(SE_AD² + SE_FD²) from the
    sample variances). The glossy weight's gradient is significantly non-zero (|mean| > 4 SE in
    every channel), so the agreement is not that of two zeros. Measured: largest |difference| /
    SE 2.0 over the 9 weight-channels (block diffuse, G); glossy |mean AD| / SE >= 40 (channel
    values -12.10, -10.70, -7.84 by AD against -11.97, -10.63, -7.81 by FD).
    """
    problem, ad, fd = glossy_gradients
    diff, se = mean_difference(ad, fd)
    assert np.all(np.abs(diff) < 4 * se), (diff / se).round(2)
    g = [p.index for p in problem.parameters if p.kernel == GLOSSY]
    assert g
    mean, sem = ad[:, g].mean(0), ad[:, g].std(0, ddof=1) / np.sqrt(REPEATS)
    assert np.all(np.abs(mean) > 4 * sem), (mean / sem).round(2)


# ------------------------------------------------------------------------------------------------
# (e) A symbolic run names its glossy parameters as the scene writes them
# ------------------------------------------------------------------------------------------------
def test_symbolic_run_names_glossy_parameters(tmp_path):
    """method=symbolic on the tiny scene with a glossy ground: the parameters, and results.json's
    rows (:func:`framework.results.parameter_rows`), name the kernel ``glossy(0.2)``; each row
    holds its parameter's estimate, and its error is the estimate less the reference."""
    from framework.results import parameter_rows
    problem = make_problem(_glossy_scene(tmp_path / "s"), ["view_0.png"], "render.spp=8")
    result = run_symbolic(problem)
    params = result.parameters or problem.parameters
    assert [(p.segment_name, p.kernel) for p in params] == [("ground", "diffuse"), ("ground", GLOSSY),
                                                           ("block", "diffuse")]
    rows = parameter_rows(problem, result)
    assert [r["kernel"] for r in rows] == ["diffuse", GLOSSY, "diffuse"]
    assert rows[1]["reference"] == [0.1, 0.15, 0.2]
    for p, row in zip(params, rows):
        np.testing.assert_allclose(row["estimate"], result.estimate[p.index], rtol=1e-12)
        np.testing.assert_allclose(row["error"], np.subtract(row["estimate"], row["reference"]), atol=1e-12)



def test_kernel_names_are_canonical_in_the_scene(tmp_path):
    """``glossy(0.20)`` in ``kernels`` and ``glossy(0.200)`` as a reference key load as the kernel
    ``glossy(0.2)``: the segment, its reference and the parameters use the canonical name."""
    from framework.scene import load_scene
    root = make_tiny_scene(tmp_path / "s", kernels=("diffuse",))

    def edit(d):
        d["segments"][0]["kernels"] = ["diffuse", "glossy(0.20)"]
        d["segments"][0]["reference"] = {"diffuse": 0.5, "glossy(0.200)": 0.1}
    edit_scene_yaml(root, edit)
    scene = load_scene(root)
    assert scene.segments[0].kernels == ("diffuse", "glossy(0.2)")
    assert set(scene.segments[0].reference) == {"diffuse", "glossy(0.2)"}
    assert [p.kernel for p in scene.parameters()][:2] == ["diffuse", "glossy(0.2)"]
