"""PolynomialPathIntegrator on analytic scenes and against Mitsuba's ``path`` (llvm_ad_rgb).

Tolerances are statistical where the estimator is random: ``4σ`` with σ estimated from
independent repetitions (per-pixel sample variance) of both estimators.
"""
import subprocess
import sys
import textwrap

import framework.render.backend

framework.render.backend.set_variant("llvm_ad_rgb")

import mitsuba as mi  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from factory import mean_and_se, mean_difference  # noqa: E402

from framework.render import kernel_bsdf as KB  # noqa: E402
from framework.errors import ConfigError  # noqa: E402
from methods.symbolic.system.basis import MonomialBasis  # noqa: E402
from methods.symbolic.trace.integrator import PolynomialPathIntegrator  # noqa: E402

T = mi.ScalarTransform4f
L_ENV = [1.0, 2.0, 3.0]



def _full(codes, mats, D, N):
    """Dense reference: per-channel sparse matrices over ``codes`` scattered into the columns of
    the full basis (all C(D + N, N) monomials), and that basis."""
    basis = MonomialBasis(D, N)
    at = np.searchsorted(basis.codes, codes)
    out = []
    for m in mats:
        dense = np.zeros((m.shape[0], basis.size))
        dense[:, at] = m.toarray()
        out.append(dense)
    return out, basis


def _coefficients(integ, scene, **kw):
    """``integ.coefficients`` in the full basis: ``(pixels, N_e, C)`` float32, and the basis."""
    codes, mats = integ.coefficients_sparse(scene, **kw)
    dense, basis = _full(codes, mats, integ.n_params, integ.max_bounces)
    return np.stack(dense, axis=-1).astype(np.float32), basis

def plane_scene(res=16):
    """Rectangle scaled 1000 (z = 0, normal +z) under a constant emitter, camera 5 above looking down."""
    return mi.load_dict({
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 40,
                   "to_world": T().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}}},
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": L_ENV}},
        "plane": {"type": "rectangle", "to_world": T().scale(1000)},
    }, optimize=False)


def test_plane_mirror_is_exact():
    """Mirror-only segment: every pixel sees the constant sky in the mirror, so γ(ρ_s) = L exactly
    (delta kernel, q = 1, no NEE) and every other monomial is 0."""
    scene = plane_scene()
    integ = PolynomialPathIntegrator.create([(scene.shapes()[0], 0)], [[("specular", 0)]], 1,
                                            np.full((1, 3), 0.5), max_bounces=3)
    c, _ = _coefficients(integ, scene, spp=4, seed=0)
    assert c.shape == (256, 4, 3)
    np.testing.assert_allclose(c[:, 1, :], np.broadcast_to(L_ENV, (256, 3)), rtol=1e-5)
    assert np.abs(np.delete(c, 1, axis=1)).max() == 0.0


def test_plane_diffuse_and_specular_kernels():
    """Segment [diffuse, specular] under a constant sky L: E[γ(ρ_d)] = E[γ(ρ_s)] = L (reflected
    radiance of a white Lambertian / perfect mirror under uniform sky), exactly 0 on the constant
    and degree >= 2 monomials (an infinite plane never sees itself). The estimate is random only
    through the kernel choice and NEE/BSDF MIS: pixel means are checked at 4σ (σ from the pixel
    spread, all pixels being identically distributed)."""
    scene = plane_scene()
    integ = PolynomialPathIntegrator.create([(scene.shapes()[0], 0)],
                                            [[("diffuse", 0), ("specular", 1)]], 2,
                                            np.array([[0.6] * 3, [0.3] * 3]), max_bounces=3)
    c, _ = _coefficients(integ, scene, spp=16, seed=1)
    for m in (1, 2):
        mean, se = mean_and_se(c[:, m])
        assert np.all(np.abs(mean - L_ENV) < 4 * se + 1e-6), (m, mean, se)
    assert np.abs(c[:, [0] + list(range(3, c.shape[1]))]).max() == 0.0
    # mirror: each sample is 0 or L/q_s exactly, so γ(ρ_s)/L is a multiple of 1/(q_s spp)
    q_s = integ.selection_probs[0][1]
    k = c[:, 2, 0] / L_ENV[0] * q_s * 16
    np.testing.assert_allclose(k, np.round(k), atol=1e-4)


def test_furnace_sphere():
    """Camera inside a closed diffuse sphere (normals inward) emitting Le: the radiance of
    bounce k is Le ρ^k (white furnace), so γ(ρ^k) = Le for k = 0..N_max; 4σ MC tolerance from the
    pixel spread (all pixels identically distributed) plus 0.5 % : Mitsuba's analytic sphere
    emitter is itself biased by ~0.27 % here (measured: ``path`` max_depth=2, 1024 spp, ρ = 0.5 gave
    1.05094 ± 0.00005 for the exact 1.05; this integrator 0.70194 for γ(ρ) = 0.7, the same excess).
    ρ^0 is exact (Le seen directly). Power: the standard error was 0.042-0.050 % of Le over seeds
    2-7 (the test uses 2), so se < 0.1 % of Le (2x the worst) keeps 4σ well below the 0.5 %."""
    Le = 0.7
    scene = mi.load_dict({
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 60,
                   "to_world": T().look_at(origin=[0, 0, 0], target=[0, 0, 1], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 16, "height": 16, "rfilter": {"type": "box"}}},
        "sphere": {"type": "sphere", "radius": 1.0, "flip_normals": True,
                   "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [Le] * 3}}},
    }, optimize=False)
    N = 3
    integ = PolynomialPathIntegrator.create([(scene.shapes()[0], 0)], [[("diffuse", 0)]], 1,
                                            np.full((1, 3), 0.5), max_bounces=N)
    c, basis = _coefficients(integ, scene, spp=32, seed=2)
    assert c.shape[1] == N + 1
    np.testing.assert_allclose(c[:, 0], Le, rtol=1e-6)
    for k in range(1, N + 1):
        m = basis.index([0] * k)
        mean, se = mean_and_se(c[:, m])
        assert np.all(np.abs(mean - Le) < 4 * se + 0.005 * Le), (k, mean, se)
        assert np.all(se < 0.001 * Le)     # the test has power


SEGMENTS = [[("diffuse", 0), ("diffuse", 1)],   # 0 white: two kernels (exercises selection)
            [("diffuse", 2)],                    # 1 red
            [("diffuse", 3)],                    # 2 green
            [("specular", 4)]]                   # 3 mirror: the large box


def cornell(rho, res=32, d=None):
    """mi.cornell_box() (or the dict ``d`` made from it) with forward kernel BSDFs
    (framework.render.kernel_bsdf.forward_bsdf + weight_keys), box filter, black emit-only light
    (segment -1); the large box is a pure mirror segment."""
    d = mi.cornell_box() if d is None else d
    d["sensor"]["film"].update({"width": res, "height": res, "rfilter": {"type": "box"}})
    d["light"]["bsdf"] = {"type": "diffuse", "reflectance": 0.0}
    seg_of = {"white": 0, "red": 1, "green": 2}
    shape_seg = {k: seg_of[d[k]["bsdf"]["id"]] for k in ("floor", "ceiling", "back", "green-wall",
                                                         "red-wall", "small-box")}
    shape_seg["large-box"] = 3
    shape_seg["light"] = -1
    d["white"] = KB.forward_bsdf(["diffuse", "diffuse"], ("R", "G", "B"))
    d["red"] = KB.forward_bsdf(["diffuse"], ("R", "G", "B"))
    d["green"] = KB.forward_bsdf(["diffuse"], ("R", "G", "B"))
    d["large-box"]["bsdf"] = KB.forward_bsdf(["specular"], ("R", "G", "B"))
    scene = mi.load_dict(d, optimize=False)
    params = mi.traverse(scene)
    for name, seg in (("white", 0), ("red", 1), ("green", 2), ("large-box.bsdf", 3)):
        kl = SEGMENTS[seg]
        for key, val in zip(KB.weight_keys(kl), rho[[p for _, p in kl]]):
            params[f"{name}.{key}"] = mi.Color3f(*[float(v) for v in val])
    params.update()
    return scene, [(s, shape_seg[s.id()]) for s in scene.shapes()]


def _z(a, b):
    """(R, ...) repetitions of two estimators -> z score of the difference of their means."""
    diff, se = mean_difference(a, b)
    return diff / se


def _polynomial_image(integ, scene, rho, spp, seed, res):
    """The polynomial of one pass (``seed``) evaluated at ``rho``: a (res, res, 3) image."""
    c, basis = _coefficients(integ, scene, spp=spp, seed=seed)
    img = np.stack([c[:, :, ch] @ basis.evaluate(rho[:, ch]) for ch in range(3)], -1)
    return img.reshape(res, res, 3)


def _assert_same_expectation(poly, ref):
    """(R, res, res, 3) repetitions of two estimators: image means and 2x2-quadrant means per
    channel agree at |z| < 4."""
    R, res = poly.shape[0], poly.shape[1]
    quads = lambda x: x.reshape(R, 2, res // 2, 2, res // 2, 3).mean((2, 4))
    assert np.all(np.abs(_z(poly.mean((1, 2)), ref.mean((1, 2)))) < 4)
    assert np.all(np.abs(_z(quads(poly), quads(ref))) < 4)


@pytest.mark.parametrize("guess", ["near", "far"])
def test_cornell_matches_path(guess):
    """Polynomial evaluated at random ρ vs mi.render(path, max_depth = N_max + 1) at independent
    seeds. Each estimator is run R = 4 times (32x32, 32 spp); image means and 2x2-quadrant means per
    channel must agree at |z| < 4 (σ from the repetition variance). 'far': guesses 0.9 while the
    true white weights are ~0.1 (only the variance may change, not the expectation). Also checks
    mi.render(polynomial integrator) (= polynomial at the guesses) against path at ρ = guesses.
    The image means' ratio is also bounded in absolute terms: |ratio - 1| measured over 6 seed
    offsets (seeds + 1000 k, k = 0-5; the test uses k = 0) was 0.0001-0.017 (near) and
    0.0005-0.024 (far), tolerance 0.04 = 1.7x the worst."""
    rng = np.random.default_rng(5 if guess == "near" else 6)
    rho = rng.uniform(0.1, 0.45, (5, 3))
    if guess == "far":
        rho[:2] = 0.1
    guesses = np.full((5, 3), 0.5) if guess == "near" else np.full((5, 3), 0.9) * [[1], [0.1], [1], [1], [1]]
    N = 3
    scene, shape_segments = cornell(rho)
    integ = PolynomialPathIntegrator.create(shape_segments, SEGMENTS, 5, guesses, max_bounces=N)
    path = mi.load_dict({"type": "path", "max_depth": N + 1, "rr_depth": 1000})
    R, spp, res = 4, 32, 32
    poly, ref = [], []
    for r in range(R):
        poly.append(_polynomial_image(integ, scene, rho, spp, 10 + r, res))
        ref.append(np.asarray(mi.render(scene, integrator=path, spp=spp, seed=100 + r)))
    poly, ref = np.array(poly), np.array(ref)
    _assert_same_expectation(poly, ref)
    assert abs(poly.mean() / ref.mean() - 1) < 0.04   # and close in absolute terms

    if guess == "near":
        scene_g, _ = cornell(guesses)
        ig = np.array([np.asarray(mi.render(scene, integrator=integ, spp=spp, seed=200 + r))
                       for r in range(R)])
        rg = np.array([np.asarray(mi.render(scene_g, integrator=path, spp=spp, seed=300 + r))
                       for r in range(R)])
        assert np.all(np.abs(_z(ig.mean((1, 2)), rg.mean((1, 2)))) < 4)


def test_tail_is_exact_at_the_guesses():
    """tail_bounces T: at ρ = guesses the polynomial equals path with max_depth = N_max + T + 1
    (|z| < 4 on image and quadrant means, R = 4 x 32 spp), and holds visibly more light than the
    truncated path (max_depth = N_max + 1): the test has power (z > 8 asserted; measured
    z >= 38 over seed offsets + 1000 k, k = 0-5)."""
    rho = np.full((5, 3), 0.6) * [[1], [0.5], [1], [1], [1]]
    N, T, R, spp, res = 1, 3, 4, 32, 32
    scene, shape_segments = cornell(rho)
    integ = PolynomialPathIntegrator.create(shape_segments, SEGMENTS, 5, rho, max_bounces=N, tail_bounces=T)
    deep = mi.load_dict({"type": "path", "max_depth": N + T + 1, "rr_depth": 1000})
    short = mi.load_dict({"type": "path", "max_depth": N + 1, "rr_depth": 1000})
    poly, ref, trunc = [], [], []
    for r in range(R):
        poly.append(_polynomial_image(integ, scene, rho, spp, 10 + r, res))
        ref.append(np.asarray(mi.render(scene, integrator=deep, spp=spp, seed=100 + r)))
        trunc.append(np.asarray(mi.render(scene, integrator=short, spp=spp, seed=100 + r)))
    poly, ref, trunc = np.array(poly), np.array(ref), np.array(trunc)
    _assert_same_expectation(poly, ref)
    assert np.all(_z(poly.mean((1, 2)), trunc.mean((1, 2))) > 8)
    with pytest.raises(ConfigError, match="tail_bounces=-1"):
        PolynomialPathIntegrator.create(shape_segments, SEGMENTS, 5, rho, tail_bounces=-1)


def test_pixel_range_and_tiles():
    """pixel_range / tile_pixels return the same pixels (first tile shares the seed, exact; later
    tiles have their own seed, so only the shape and the deterministic constant monomial match)."""
    scene, ss = cornell(np.full((5, 3), 0.3), res=16)
    a = PolynomialPathIntegrator.create(ss, SEGMENTS, 5, np.full((5, 3), 0.3), max_bounces=2)
    full, _ = _coefficients(a, scene, spp=4, seed=3)
    part, _ = _coefficients(a, scene, spp=4, seed=3, pixel_range=(0, 100))
    np.testing.assert_array_equal(part, full[:100])
    b = PolynomialPathIntegrator.create(ss, SEGMENTS, 5, np.full((5, 3), 0.3), max_bounces=2,
                                        tile_pixels=50)
    tiled, _ = _coefficients(b, scene, spp=4, seed=3)
    assert tiled.shape == full.shape == (256, 21, 3)
    np.testing.assert_array_equal(tiled[:50], full[:50])


def test_halves_split_the_samples():
    """coefficients_halves: Γ = (A + B) / 2 at even spp, A and B differ (different samples), and
    each half is an unbiased estimate: per-pixel coefficients of A, B (R = 4 seeds x 16 spp) and
    of coefficients_sparse (independent seeds) agree in their column totals over the image at
    |z| < 4 (σ from the repetition variance), on the monomials of degree <= 1."""
    scene, ss = cornell(np.full((5, 3), 0.3), res=16)
    integ = PolynomialPathIntegrator.create(ss, SEGMENTS, 5, np.full((5, 3), 0.3), max_bounces=2)
    _, A, B, G = integ.coefficients_halves(scene, spp=4, seed=3)
    for c in range(3):
        np.testing.assert_allclose(G[c].toarray(), (A[c] + B[c]).toarray() / 2, rtol=1e-6, atol=1e-9)
        assert abs(A[c] - B[c]).max() > 0
    low = np.flatnonzero(MonomialBasis(5, 2).degrees <= 1)
    total = lambda codes, mats: np.stack([m[:, low].sum(0) for m in _full(codes, mats, 5, 2)[0]])  # (C, monomials)
    halves = [integ.coefficients_halves(scene, spp=16, seed=20 + r) for r in range(4)]
    a = np.array([total(h[0], h[1]) for h in halves])
    b = np.array([total(h[0], h[2]) for h in halves])
    full = np.array([total(*integ.coefficients_sparse(scene, spp=16, seed=40 + r)) for r in range(4)])
    seen = full.mean(0) > 1e-3 * full.mean(0).max()
    assert seen.sum() >= 6                                                 # the test has power
    for x in (a, b):
        assert np.all(np.abs(_z(x[:, seen], full[:, seen])) < 4)
    with pytest.raises(ConfigError, match="spp=1"):
        integ.coefficients_halves(scene, spp=1)


def test_quarters_split_each_half():
    """coefficients_halves(quarters=True): A, B and Γ are those of the same render without
    quarters (same bits: the quarters only add two matrices); A₁ holds the first half of A's
    samples, so A = (A₁ + A₂) / 2 with A₂ = 2A - A₁ another estimate that differs from A₁; and
    the quarters A₁, B₁ are unbiased: their column totals (4 seeds x 16 spp) agree with those of
    coefficients_sparse at |z| < 4, as the halves' do in test_halves_split_the_samples."""
    scene, ss = cornell(np.full((5, 3), 0.3), res=16)
    integ = PolynomialPathIntegrator.create(ss, SEGMENTS, 5, np.full((5, 3), 0.3), max_bounces=2)
    plain = integ.coefficients_halves(scene, spp=8, seed=3)
    codes, A, B, G, A1, B1 = integ.coefficients_halves(scene, spp=8, seed=3, quarters=True)
    np.testing.assert_array_equal(codes, plain[0])
    for c in range(3):
        for m, ref in ((A, plain[1]), (B, plain[2]), (G, plain[3])):
            assert abs(m[c] - ref[c]).max() == 0
        for half, first in ((A, A1), (B, B1)):
            second = 2 * half[c] - first[c]
            assert abs(first[c] - second).max() > 0
            assert first[c].nnz <= half[c].nnz
    low = np.flatnonzero(MonomialBasis(5, 2).degrees <= 1)
    total = lambda codes, mats: np.stack([m[:, low].sum(0) for m in _full(codes, mats, 5, 2)[0]])  # (C, monomials)
    runs = [integ.coefficients_halves(scene, spp=16, seed=20 + r, quarters=True) for r in range(4)]
    full = np.array([total(*integ.coefficients_sparse(scene, spp=16, seed=40 + r)) for r in range(4)])
    seen = full.mean(0) > 1e-3 * full.mean(0).max()
    assert seen.sum() >= 6
    for k in (4, 5):
        x = np.array([total(r[0], r[k]) for r in runs])
        assert np.all(np.abs(_z(x[:, seen], full[:, seen])) < 4)


def test_quarters_errors():
    scene, ss = cornell(np.full((5, 3), 0.3), res=8)
    integ = PolynomialPathIntegrator.create(ss, SEGMENTS, 5, np.full((5, 3), 0.3), max_bounces=2)
    with pytest.raises(ConfigError, match="spp=6: four independent quarters need spp a multiple of 4"):
        integ.coefficients_halves(scene, spp=6, quarters=True)


def _split_plane(res=16):
    """:func:`plane_scene` cut in two segments along world x = 0 (image column ``res / 2``)."""
    half = lambda x0: {"type": "rectangle", "to_world": T().translate([x0, 0, 0]).scale([500, 1000, 1]),  # noqa: E731
                       "bsdf": {"type": "diffuse"}}
    scene = mi.load_dict({
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 40,
                   "to_world": T().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}}},
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": L_ENV}},
        "left": half(-500), "right": half(500),
    }, optimize=False)
    return scene, [(scene.shapes()[0], 0), (scene.shapes()[1], 1)]


@pytest.mark.parametrize("kernel", ["bilinear", "cubic"])
def test_footprint_integrates_over_the_resampled_source_pixels(kernel):
    """A view whose photographs were resampled from a distorted camera (OPENCV, fx != fy) renders
    each pixel over its footprint (:meth:`Resampling.footprint`): the coefficient of the segment
    on one side of a straight edge (under a constant sky, L · the share of the pixel on that
    side) is ``L sum_k w_k a_k`` with ``a_k`` the share of source pixel k's parallelogram on
    that side (computed here on a 64 x 64 grid of each parallelogram), where the plain box gives
    0 or 1 (the edge lies on a pixel border). Tolerance 5 σ of a pixel's estimate,
    σ = L · sum |w| / (2 sqrt(spp)) (a Bernoulli draw times the weight's magnitude; the sky's
    sampling adds ~0.5 % of L, measured, well inside it)."""
    import pycolmap
    from framework.scene.undistort import Resampling
    res, spp = 16, 4096
    scene, shapes = _split_plane(res)
    f = res / 2 / np.tan(np.radians(20.0))
    target = pycolmap.Camera(model="PINHOLE", width=res, height=res, params=[f, f, res / 2, res / 2])
    source = pycolmap.Camera(model="OPENCV", width=res, height=res,
                             params=[0.93 * f, 0.9 * f, res / 2 + 0.37, res / 2 - 0.21, -0.05, 0.01, 0.002, -0.001])
    r = Resampling(source=source, target=target, kernel=kernel)
    integ = PolynomialPathIntegrator.create(shapes, [[("diffuse", 0)], [("diffuse", 1)]], 2,
                                            np.full((2, 3), 0.5), max_bounces=1)
    plain, _ = _coefficients(integ, scene, spp=64, seed=1)
    left = plain[:, 1, 0].reshape(res, res)[:, 0] > 0       # which side the first segment shows
    fp = r.footprint()
    g = (np.arange(64) + 0.5) / 64 - 0.5
    u, v = [a.ravel() for a in np.meshgrid(g, g)]
    j = fp.jacobian[:, None, :, :, None]                   # the pixel's, for each of its source pixels
    x = fp.position[..., 0, None] + j[:, :, 0, 0] * u + j[:, :, 0, 1] * v
    share = ((x < res / 2) if left.all() else (x > res / 2)).mean(axis=-1)
    expected = L_ENV[0] * (fp.weight * share).sum(axis=1)
    c, _ = _coefficients(integ, scene, spp=spp, seed=2, footprint=r)
    σ = L_ENV[0] * np.abs(fp.weight).sum(axis=1) / (2 * np.sqrt(spp))
    assert np.all(np.abs(c[:, 1, 0] - expected) <= 5 * σ)
    assert np.abs(plain[:, 1, 0] - expected).max() > 20 * σ.max()      # the blur is there to find


def test_footprint_errors():
    import pycolmap
    from framework.scene.undistort import Resampling
    scene, shapes = _split_plane(16)
    integ = PolynomialPathIntegrator.create(shapes, [[("diffuse", 0)], [("diffuse", 1)]], 2,
                                            np.full((2, 3), 0.5), max_bounces=1)
    other = pycolmap.Camera(model="PINHOLE", width=12, height=16, params=[20.0, 20.0, 6.0, 8.0])
    with pytest.raises(ConfigError, match="footprint of a 12x16 camera for a film of 16x16"):
        integ.coefficients_sparse(scene, spp=1, footprint=Resampling(source=other, target=other))
    cropped = mi.load_dict({"type": "perspective", "fov": 40, "film": {
        "type": "hdrfilm", "width": 16, "height": 16, "crop_offset_x": 2, "crop_width": 8, "rfilter": {"type": "box"}}})
    own = pycolmap.Camera(model="PINHOLE", width=16, height=16, params=[20.0, 20.0, 8.0, 8.0])
    with pytest.raises(ConfigError, match="needs the whole film: no crop window"):
        integ.coefficients_sparse(scene, cropped, spp=1, footprint=Resampling(source=own, target=own))


def test_event_csr_matches_scipy_coo():
    """_csr (one within-row sort shared by the channels) equals scipy's COO -> CSR conversion,
    duplicates summed, on random events with sorted rows."""
    from methods.symbolic.trace.events import csr as _csr
    import scipy.sparse as sp
    rng = np.random.default_rng(0)
    rows = np.sort(rng.integers(0, 50, 2000))
    cols = rng.integers(0, 7, 2000)
    vals = rng.normal(size=(2, 2000))
    mats = _csr(rows, cols, vals, (60, 7))
    for c in range(2):
        ref = sp.coo_matrix((vals[c], (rows, cols)), shape=(60, 7)).toarray()
        np.testing.assert_allclose(mats[c].toarray(), ref, rtol=1e-12, atol=1e-12)
        assert mats[c].nnz == np.count_nonzero(ref) and np.all(np.diff(mats[c].indptr) >= 0)
    assert all(m.nnz == 0 and m.shape == (60, 7) for m in _csr(rows[:0], cols[:0], vals[:, :0], (60, 7)))


def test_a_views_last_smaller_tile_reuses_the_full_tiles_buffers():
    """Dr.Jit's allocator (its watermark) rounds a buffer to a power of two and hands a freed one
    only to a request of that size: a 100,000-lane tile's event buffers (8 slots, RGB) peak at
    16 MiB, and a 30,000-lane last tile sized as itself adds 4 MiB beside them (measured, Dr.Jit
    1.5); sized as the full tile (``capacity``) it takes them again, and its extra lanes hold no
    event."""
    import drjit as dr
    from methods.symbolic.trace.events import EventBuffer
    MiB = 2 ** 20

    def written(n, capacity):
        events = EventBuffer(n, 8, 3, capacity=capacity)
        for a in [events.mono] + events.values:          # one event, as the trace writes them
            dr.scatter(a, type(a)(1), mi.UInt32(0))
        dr.eval(events.mono, events.values)
        return events

    def peak(capacity, lanes=(100_000, 30_000)):
        dr.flush_malloc_cache()
        dr.detail.malloc_clear_statistics()
        base = dr.detail.malloc_watermark(dr.JitBackend.LLVM)
        for n in lanes:
            written(n, capacity)         # freed at once: its buffers go to the allocator's cache
        return (dr.detail.malloc_watermark(dr.JitBackend.LLVM) - base) / MiB

    one_tile = peak(None, lanes=(100_000,))
    assert one_tile == 16.0
    assert peak(None) == one_tile + 4.0
    assert peak(100_000) == one_tile
    padded = written(30_000, 100_000)
    assert dr.width(padded.mono) == 800_000 and dr.count(padded.nonempty())[0] == 1


def test_chunk_bounds_by_hand():
    """Consecutive chunks within every budget (worked by hand), a pixel over budget alone."""
    from methods.symbolic.trace.pixel_sums import _chunk_bounds
    assert _chunk_bounds([np.array([3, 3, 3, 3])], [6]) == [(0, 2), (2, 2)]
    assert _chunk_bounds([np.array([3, 3, 3, 3])], [7]) == [(0, 2), (2, 2)]
    assert _chunk_bounds([np.array([1, 9, 1, 1])], [5]) == [(0, 1), (1, 1), (2, 2)]
    assert _chunk_bounds([np.array([1, 1, 1, 1]), np.array([2, 2, 2, 2])], [10, 4]) == [(0, 2), (2, 2)]
    assert _chunk_bounds([np.array([1, 1, 1])], [100]) == [(0, 3)]


def test_device_sums_stay_within_a_share_of_the_event_buffers(monkeypatch):
    """The worst case of the device sums' memory: every event its own (pixel, monomial) cell (a
    pixel's 16 slots hold 16 distinct keys, 8,192 pixels x 4 spp x 4 slots, RGB: 2 MiB of event
    buffers, E). Dr.Jit's allocation watermark above the event buffers stays within E, the share
    of ``method.memory_mb`` (3 E) left when the event buffers round up to 2 E; with chunks and
    parts as large as the events (``SUMS_SHARE`` 1) the same tile took 5.75 MiB (measured, Dr.Jit
    1.5). Both give the same bits."""
    import drjit as dr
    import methods.symbolic.trace.pixel_sums as PS
    from methods.symbolic.trace.events import EventBuffer
    n, spp, slots, MiB = 8192, 4, 4, 2 ** 20

    def summed(share):
        events = EventBuffer(n * spp, slots, 3)
        slot = dr.arange(mi.UInt32, n * spp * slots)
        dr.scatter(events.mono, slot % (spp * slots), slot)
        for v in events.values:
            dr.scatter(v, mi.Float(slot) * 1e-3, slot)
        dr.eval(events.mono, events.values)
        monkeypatch.setattr(PS, "SUMS_SHARE", share)
        dr.flush_malloc_cache()
        dr.detail.malloc_clear_statistics()
        base = dr.detail.malloc_watermark(dr.JitBackend.LLVM)
        codes, mats = PS.pixel_sums(events, n=n, spp=spp, split=spp // 2, quarters=False, span=spp * slots,
                                    columns=lambda keys: (keys, np.arange(len(keys))))
        extra = (dr.detail.malloc_watermark(dr.JitBackend.LLVM) - base) / MiB
        return events.nbytes() / MiB, extra, mats

    E, extra, parts = summed(PS.SUMS_SHARE)
    assert E == 2.0 and parts[0][0].nnz == n * spp * slots // 2           # one cell per event
    assert extra <= E
    _, whole_extra, whole = summed(1)
    assert whole_extra > 2 * E
    for p, w in zip(parts, whole):
        for c in range(3):
            np.testing.assert_array_equal(p[c].indptr, w[c].indptr)
            np.testing.assert_array_equal(p[c].data, w[c].data)


def test_config_errors():
    with pytest.raises(ConfigError, match=r"max_bounces=0.*\[1"):
        PolynomialPathIntegrator.create([], [[("diffuse", 0)]], 1, np.ones((1, 3)), max_bounces=0)
    with pytest.raises(ConfigError, match="parameter index 3"):
        PolynomialPathIntegrator.create([], [[("diffuse", 3)]], 1, np.ones((1, 3)))
    with pytest.raises(Exception, match="unknown kernel"):
        PolynomialPathIntegrator.create([], [[("glossy", 0)]], 1, np.ones((1, 3)))


@pytest.mark.slow
def test_mono_variant_in_subprocess():
    """llvm_ad_mono (C = 1): the exact mirror-plane case, in a fresh process (a Mitsuba class is
    bound to the variant active when its module is imported)."""
    code = textwrap.dedent("""
        import framework.render.backend; framework.render.backend.set_variant('llvm_ad_mono')
        import mitsuba as mi, numpy as np
        from methods.symbolic.trace.integrator import PolynomialPathIntegrator
        T = mi.ScalarTransform4f
        s = mi.load_dict({'type': 'scene', 'sensor': {'type': 'perspective', 'fov': 40,
            'to_world': T().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
            'film': {'type': 'hdrfilm', 'width': 8, 'height': 8, 'rfilter': {'type': 'box'}}},
            'env': {'type': 'constant', 'radiance': 2.5},
            'plane': {'type': 'rectangle', 'to_world': T().scale(1000)}}, optimize=False)
        i = PolynomialPathIntegrator.create([(s.shapes()[0], 0)], [[('specular', 0)]], 1, [[0.5]])
        codes, c = i.coefficients(s, spp=4, seed=0)
        assert codes.tolist() == [0, 1] and c.shape == (64, 2, 1), (codes, c.shape)
        assert np.allclose(c[:, 1, 0], 2.5, rtol=1e-5) and np.abs(c[:, 0]).max() == 0
        img = np.asarray(mi.render(s, integrator=i, spp=4))
        assert np.allclose(img, 1.25, rtol=1e-5), img.mean()
        print('OK')
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and "OK" in out.stdout, out.stderr[-2000:]


def _lit_cornell(rho, light_scale=1.0, res=16):
    """:func:`cornell` with its ceiling light's radiance times ``light_scale`` and a constant sky
    (0.5) seen through the open front: two emitters."""
    d = mi.cornell_box()
    d["light"]["emitter"]["radiance"]["value"] = [v * light_scale for v in d["light"]["emitter"]["radiance"]["value"]]
    d["sky"] = {"type": "constant", "radiance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}}
    return cornell(rho, res, d)


def test_emitter_groups_carry_the_scale():
    """An unknown emitter scale is one more variable: the pass keyed by the emitter group, at
    scale ``s``, equals the plain pass of the scene whose light is ``s`` times brighter. The same
    seed draws the same paths (emitter selection does not depend on the emitters' power), so
    the two agree to float32 rounding (sums in another order), not only in expectation."""
    rho = np.full((5, 3), 0.4)
    N, spp, res, s = 2, 4, 16, 2.5
    scene, shapes = _lit_cornell(rho, res=res)
    light = [sh.emitter() for sh, _ in shapes if sh.emitter() is not None]
    grouped = PolynomialPathIntegrator.create(shapes, SEGMENTS, 5, rho, max_bounces=N, emitter_groups=[(light[0], 1)])
    assert grouped.event_slots() == 1 + 2 * N
    codes, mats = grouped.coefficients_sparse(scene, spp=spp, seed=3)
    basis = MonomialBasis(6, N + 1, codes)                # ρ (5) and the light's scale, degree N + 1
    at = lambda scale: np.stack([mats[c] @ basis.evaluate(np.r_[rho[:, c], scale]) for c in range(3)], -1)
    for scale in (0.0, 1.0, s):                           # 0: the sky's light alone
        sc, sh = _lit_cornell(rho, light_scale=scale, res=res)
        plain = PolynomialPathIntegrator.create(sh, SEGMENTS, 5, rho, max_bounces=N)
        ref = _polynomial_image(plain, sc, rho, spp, 3, res).reshape(-1, 3)
        assert ref.max() > 0
        np.testing.assert_allclose(at(scale), ref, rtol=1e-4, atol=1e-6 * ref.max())


def _two_skies(image, res=16):
    """A diffuse ground plane (segment 0) under an environment that is the sum of the envmap
    ``image`` and a constant sky 0.5, the camera seeing ground below and sky above the horizon."""
    sky = np.ascontiguousarray(image + 0.5, np.float32)
    d = {"type": "scene",
         "sensor": {"type": "perspective", "fov": 60,
                    "to_world": T().look_at(origin=[0, 0, 1], target=[5, 0, 0.6], up=[0, 0, 1]),
                    "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}}},
         "env": {"type": "envmap", "bitmap": mi.Bitmap(sky)},
         "ground": {"type": "rectangle", "to_world": T().scale(100), "bsdf": KB.forward_bsdf(["diffuse"], ("R", "G", "B"))}}
    scene = mi.load_dict(d, optimize=False)
    params = mi.traverse(scene)
    params[f"ground.bsdf.{KB.weight_keys(['diffuse'])[0]}"] = mi.Color3f(0.6, 0.5, 0.4)
    params.update()
    return scene


def test_environment_parts_split_the_sum():
    """Two environments Mitsuba renders as one (their sum): the pass splits each contribution of
    the sum by the parts' radiance along its direction. At the declared scale (1) the grouped
    polynomial is the plain pass of the same scene (same paths: float32 rounding only); sky
    pixels at scale ``s`` are ``s·A + 0.5`` exactly; ground pixels at ``s = 2.5`` agree in
    expectation (|z| < 4, 4 seeds) with the plain pass of the scene whose envmap is ``2.5·A``."""
    rng = np.random.default_rng(0)
    A = np.zeros((8, 16, 3), np.float32)
    A[1:3, 2:6] = 40.0 * rng.random((2, 4, 3))            # a bright patch above the horizon
    A += np.linspace(0.1, 1.0, 16, dtype=np.float32)[None, :, None]
    rho, N, spp, res = np.array([[0.6, 0.5, 0.4]]), 2, 8, 16
    scene = _two_skies(A, res)
    shapes = [(scene.shapes()[0], 0)]
    parts = [(mi.load_dict({"type": "envmap", "bitmap": mi.Bitmap(np.ascontiguousarray(A))}), 1),
             (mi.load_dict({"type": "constant", "radiance": 0.5}), 0)]
    grouped = PolynomialPathIntegrator.create(shapes, [[("diffuse", 0)]], 1, rho, max_bounces=N,
                                              environment=scene.environment(), environment_parts=parts)
    assert grouped.event_slots() == 2 * (1 + 2 * N)
    plain = PolynomialPathIntegrator.create(shapes, [[("diffuse", 0)]], 1, rho, max_bounces=N)

    def at(seed, scale):
        codes, mats = grouped.coefficients_sparse(scene, spp=spp, seed=seed)
        basis = MonomialBasis(2, N + 1, codes)
        return np.stack([mats[c] @ basis.evaluate(np.r_[rho[0, c], scale]) for c in range(3)], -1)

    ref = _polynomial_image(plain, scene, rho, spp, 3, res).reshape(-1, 3)
    np.testing.assert_allclose(at(3, 1.0), ref, rtol=1e-4, atol=1e-6 * ref.max())
    sky = np.zeros(res * res, bool)
    sky[: res * res // 4] = True                           # the top rows see only sky
    np.testing.assert_allclose(at(3, 0.0)[sky], 0.5, rtol=1e-5)
    np.testing.assert_allclose(at(3, 2.5)[sky], 2.5 * (ref[sky] - 0.5) + 0.5, rtol=1e-4)

    bright = _two_skies(2.5 * A, res)
    ref_plain = PolynomialPathIntegrator.create([(bright.shapes()[0], 0)], [[("diffuse", 0)]], 1, rho, max_bounces=N)
    poly = np.stack([at(s, 2.5).reshape(res, res, 3) for s in range(4)])
    truth = np.stack([_polynomial_image(ref_plain, bright, rho, spp, 10 + s, res) for s in range(4)])
    _assert_same_expectation(poly, truth)


def _both_sums(integ, call, monkeypatch):
    """``call()`` with the events summed on the device, then on the host (the same render)."""
    out = []
    for device in (True, False):
        monkeypatch.setattr(type(integ), "device_sums", device)
        out.append(call())
    return out


def _assert_same_matrices(device, host):
    """Same codes, same sparsity, values equal to float32 rounding (the device sums in float32
    in another order; the host sums float32 values in float64)."""
    np.testing.assert_array_equal(device[0], host[0])
    assert len(device) == len(host)
    for d, h in zip(device[1:], host[1:]):
        for c in range(len(h)):
            assert d[c].has_canonical_format
            np.testing.assert_array_equal(d[c].indptr, h[c].indptr)
            np.testing.assert_array_equal(d[c].indices, h[c].indices)
            np.testing.assert_allclose(d[c].data, h[c].data, rtol=2e-6, atol=1e-7 * abs(h[c].data).max())


@pytest.mark.parametrize("quarters", [False, True])
def test_device_sums_equal_host_sums(quarters, monkeypatch):
    """Coefficients summed per pixel and monomial on the device (methods.symbolic.trace.pixel_sums) and
    on the host (events.tile_matrices) from the same render: same codes and sparsity, values to
    float32 rounding, for the halves (and quarters) over several tiles, for halves of unequal
    sample counts and for the plain pass; the device sums of one render are the same bits every
    time (each cell summed by one lane, in order)."""
    rho = np.full((5, 3), 0.3)
    scene, ss = cornell(rho, res=16)
    integ = PolynomialPathIntegrator.create(ss, SEGMENTS, 5, rho, max_bounces=3, tile_pixels=100)
    halves = lambda: integ.coefficients_halves(scene, spp=8, seed=5, quarters=quarters)
    device, host = _both_sums(integ, halves, monkeypatch)
    _assert_same_matrices(device, host)
    monkeypatch.setattr(type(integ), "device_sums", True)
    again = halves()                                   # deterministic: the same render, the same bits
    for d, a in zip(device[1:], again[1:]):
        for c in range(3):
            assert abs(d[c] - a[c]).max() == 0
    plain = lambda: integ.coefficients_sparse(scene, spp=4, seed=5)
    _assert_same_matrices(*_both_sums(integ, plain, monkeypatch))
    odd = lambda: integ.coefficients_halves(scene, spp=7, seed=5)      # halves of 3 and 4 samples
    _assert_same_matrices(*_both_sums(integ, odd, monkeypatch))


@pytest.mark.parametrize("quarters", [False, True])
@pytest.mark.parametrize("cut", ["bitmap", "sums"])
def test_device_sums_in_chunks_of_pixels(quarters, cut, monkeypatch):
    """A tile summed a few pixels at a time gives the same codes, sparsity and bits as summed
    whole, each cell still summed by one lane in slot order: cut by its bitmap (``CHUNK_CELLS``
    lowered: each chunk marks and ranks its own pixels' events) or by its summed cells
    (``SUMS_SHARE`` raised: a chunk's cells summed in parts); each 100-pixel tile takes several."""
    import methods.symbolic.trace.pixel_sums as PS
    rho = np.full((5, 3), 0.3)
    scene, ss = cornell(rho, res=16)
    integ = PolynomialPathIntegrator.create(ss, SEGMENTS, 5, rho, max_bounces=3, tile_pixels=100)
    monkeypatch.setattr(type(integ), "device_sums", True)
    for call in (lambda: integ.coefficients_halves(scene, spp=8, seed=5, quarters=quarters),
                 lambda: integ.coefficients_sparse(scene, spp=4, seed=5)):
        whole = call()
        parts = []
        part = PS._Tile._part
        with monkeypatch.context() as patch:
            patch.setattr(PS._Tile, "_part", lambda tile, p0, m, q0, mq, *a: parts.append((m, mq)) or
                          part(tile, p0, m, q0, mq, *a))
            patch.setattr(PS, "SUMS_SHARE", 1 if cut == "bitmap" else 16)    # 1: a chunk's cells in one part
            if cut == "bitmap":
                patch.setattr(PS, "CHUNK_CELLS", 1000)
            chunked = call()
        chunk = [m for m, _ in parts] if cut == "bitmap" else [mq for _, mq in parts]
        assert len(parts) > 3 * 3 and min(chunk) < max(chunk) < 100    # several chunks per tile
        # by the bitmap each chunk is summed whole; by the cells, chunks are summed in parts
        assert all(mq == m for m, mq in parts) if cut == "bitmap" else any(mq < m for m, mq in parts)
        np.testing.assert_array_equal(chunked[0], whole[0])
        for c_block, w_block in zip(chunked[1:], whole[1:]):
            for c, w in zip(c_block, w_block):
                assert c.has_canonical_format
                for name in ("indptr", "indices", "data"):
                    np.testing.assert_array_equal(getattr(c, name), getattr(w, name))


def test_device_sums_with_emitter_groups_and_wide_keys(monkeypatch):
    """With an unknown emitter scale (keys carry the emitter's group) the device sums equal the
    host's; a key range beyond the key table (TABLE_KEYS) falls back to the host path."""
    import methods.symbolic.trace.pixel_sums as PS
    rho = np.full((5, 3), 0.4)
    scene, shapes = _lit_cornell(rho, res=16)
    light = [sh.emitter() for sh, _ in shapes if sh.emitter() is not None]
    grouped = PolynomialPathIntegrator.create(shapes, SEGMENTS, 5, rho, max_bounces=2, emitter_groups=[(light[0], 1)])
    run = lambda: grouped.coefficients_halves(scene, spp=4, seed=3)
    device, host = _both_sums(grouped, run, monkeypatch)
    _assert_same_matrices(device, host)
    monkeypatch.setattr(PS, "TABLE_KEYS", 8)
    monkeypatch.setattr(type(grouped), "device_sums", True)
    fallback = run()
    for d, h in zip(fallback[1:], host[1:]):
        for c in range(3):
            assert abs(d[c] - h[c]).max() == 0          # the host path itself: the same bits


def test_device_sums_of_a_dark_tile(monkeypatch):
    """A scene without light: no event reaches the sums; the coefficients are the constant monomial's
    empty column on both paths (Dr.Jit cannot divide an empty array: the device path stops first)."""
    scene = mi.load_dict({"type": "scene", "sensor": plane_scene().sensors()[0],
                          "plane": {"type": "rectangle", "to_world": T().scale(1000)}}, optimize=False)
    integ = PolynomialPathIntegrator.create([(scene.shapes()[0], 0)], [[("diffuse", 0)]], 1,
                                            np.full((1, 3), 0.5), max_bounces=2)
    device, host = _both_sums(integ, lambda: integ.coefficients_halves(scene, spp=4, seed=1), monkeypatch)
    np.testing.assert_array_equal(device[0], [0])
    for m in device[1] + device[2] + host[1]:
        assert m.shape == (256, 1) and m.nnz == 0
