"""Field photographs as delivered: 8/16-bit PNG, JPEG and EXR decoded to linear radiance, the
pixels that must not be used (saturated, black-clipped, masked, outside the delivered image)
weighted 0, the quantisation noise, the ``<stem>.exr`` rule, and an undistorted synthetic
photograph that equals the pinhole render within Monte Carlo error."""
from __future__ import annotations

import numpy as np
import pytest
from factory import distorted, edit_scene_yaml, make_field_scene, write_png8, write_png16

from framework.images import srgb_decode, srgb_encode, write_exr
from framework.scene import Camera, load_scene
from framework.scene.undistort import Resampling, pinhole_for, resample
from framework.scene.model import EXCLUSION_REASONS

SQRT12 = np.sqrt(12.0)


def _slope(encoded):
    """d srgb_decode / d encoded, written out from IEC 61966-2-1 (independent of the loader's)."""
    encoded = np.asarray(encoded, float)
    return np.where(encoded <= 0.04045, 1 / 12.92, 2.4 / 1.055 * ((encoded + 0.055) / 1.055) ** 1.4)


def _codes(rng, shape, top=255):
    """Codes away from the clipping limits (1 .. 0.98 top)."""
    return rng.integers(1, int(0.98 * top), shape)


# ----------------------------------------------------------------------------------------------
# Decoding: sRGB 8-bit PNG and JPEG, 16-bit PNG, EXR
# ----------------------------------------------------------------------------------------------

def test_srgb_png8_decodes_within_the_quantisation(tiny_scene):
    """Linear values written as rounded 8-bit sRGB codes come back within half a code step
    (times the curve's slope), and the noise is slope(code) * (1/255) / sqrt(12)."""
    rng = np.random.default_rng(0)
    linear = rng.uniform(0.002, 0.9, (2, 16, 16, 3))
    for i in range(2):
        write_png8(tiny_scene / "images" / f"view_{i}.png", np.round(srgb_encode(linear[i]) * 255))
    scene = load_scene(tiny_scene)
    assert scene.weights is None and scene.photometry.encoding is None
    for i in range(2):
        encoded = np.round(srgb_encode(linear[i]) * 255) / 255
        image = scene.images[f"view_{i}.png"]
        assert image.dtype == np.float32 and image.shape == (16, 16, 3)
        # the slope grows with the code: its value half a step up bounds it over the rounding
        assert (np.abs(image - linear[i]) <= 0.5 / 255 * _slope(encoded + 0.5 / 255) + 1e-7).all()
        np.testing.assert_allclose(scene.noise[f"view_{i}.png"], _slope(encoded) / 255 / SQRT12, rtol=1e-5)


def test_jpeg_decodes_within_the_quantisation(tiny_scene):
    """JPEG at quality 100 without chroma subsampling, in constant 8x8 blocks (DCT keeps only
    the DC term): within one code (YCbCr rounding) plus half a step of the linear values."""
    rng = np.random.default_rng(1)
    blocks = srgb_decode(np.round(srgb_encode(rng.uniform(0.01, 0.8, (2, 2, 2, 3))) * 255) / 255)
    linear = np.repeat(np.repeat(blocks, 8, axis=1), 8, axis=2)
    for i in range(2):
        write_png8(tiny_scene / "images" / f"view_{i}.jpg", np.round(srgb_encode(linear[i]) * 255), fmt="JPEG",
                   quality=100, subsampling=0)
    text = (tiny_scene / "sparse/images.txt").read_text().replace(".png", ".jpg")
    (tiny_scene / "sparse/images.txt").write_text(text)
    scene = load_scene(tiny_scene)
    for i in range(2):
        bound = 1.5 / 255 * _slope(srgb_encode(linear[i]) + 1 / 255)
        assert (np.abs(scene.images[f"view_{i}.jpg"] - linear[i]) <= bound).all()


def test_png16_colour_and_grey_keep_16_bits(tmp_path):
    """16-bit colour (Pillow would keep 8 bits) and grey (a mono scene) PNGs: every code read,
    linear encoding declared: value = code / 65535; noise = (1/65535) / sqrt(12)."""
    from factory import make_tiny_scene
    for channels, shape in (("rgb", (16, 16, 3)), ("mono", (16, 16))):
        root = make_tiny_scene(tmp_path / channels, channels=channels)
        edit_scene_yaml(root, lambda d: d.update(photometry={"encoding": "linear"}))
        codes = _codes(np.random.default_rng(2), (2, *shape), top=65535)
        codes[:, 0, 0] = 257 * 100 + 1          # its low byte differs from its high byte
        for i in range(2):
            write_png16(root / "images" / f"view_{i}.png", codes[i])
        scene = load_scene(root)
        assert scene.photometry.encoding == "linear"
        for i in range(2):
            expected = (codes[i] / 65535).reshape(16, 16, -1)
            np.testing.assert_allclose(scene.images[f"view_{i}.png"], expected, rtol=1e-6, atol=0)
            np.testing.assert_allclose(scene.noise[f"view_{i}.png"], 1 / 65535 / SQRT12, rtol=1e-6)


def test_png16_srgb_and_rgba(tiny_scene):
    """16-bit sRGB decodes through the sRGB curve; an alpha channel is dropped (8 and 16 bit)."""
    codes = _codes(np.random.default_rng(3), (16, 16, 4), top=65535)
    write_png16(tiny_scene / "images/view_0.png", codes)
    high_bytes = np.maximum(codes >> 8, 1)                       # code 0 would be black-clipped
    write_png8(tiny_scene / "images/view_1.png", high_bytes)
    scene = load_scene(tiny_scene)
    assert scene.weights is None
    np.testing.assert_allclose(scene.images["view_0.png"], srgb_decode(codes[..., :3] / 65535), rtol=1e-6)
    np.testing.assert_allclose(scene.images["view_1.png"], srgb_decode(high_bytes[..., :3] / 255), rtol=1e-6)


def test_stem_exr_rule_still_works(tiny_scene):
    """images/<stem>.exr: read as before (no weights, no noise, values exact); a delivered
    images/<name> next to it is read instead; a declared saturation applies to EXR too."""
    values = np.random.default_rng(4).uniform(0.0, 2.0, (2, 16, 16, 3)).astype(np.float32)
    (tiny_scene / "images").mkdir()
    for i in range(2):
        write_exr(tiny_scene / "images" / f"view_{i}.exr", values[i])
    scene = load_scene(tiny_scene)
    assert scene.weights is None and scene.noise is None
    assert all(np.array_equal(scene.images[f"view_{i}.png"], values[i]) for i in range(2))
    before = scene.content_hash
    write_png8(tiny_scene / "images/view_0.png", np.full((16, 16, 3), 100))
    scene = load_scene(tiny_scene)
    assert scene.content_hash != before
    np.testing.assert_allclose(scene.images["view_0.png"], srgb_decode(100 / 255), rtol=1e-6)
    assert np.array_equal(scene.images["view_1.png"], values[1]) and scene.noise["view_1.png"].max() == 0
    (tiny_scene / "images/view_0.png").unlink()
    edit_scene_yaml(tiny_scene, lambda d: d.update(photometry={"saturation": 1.5 / 2}))
    scene = load_scene(tiny_scene)
    for i in range(2):
        usable = (values[i] < 0.75).all(axis=2)
        assert np.array_equal(scene.weights[f"view_{i}.png"], usable.astype(np.float32))
        assert np.array_equal(scene.images[f"view_{i}.png"], np.where(usable[..., None], values[i], 0))


# ----------------------------------------------------------------------------------------------
# Unusable pixels
# ----------------------------------------------------------------------------------------------

def test_saturated_black_and_masked_pixels_weigh_zero(tiny_scene):
    """8-bit: a code >= 0.99 * 255 (253) or 0 in any channel, or a mask value 0: weight 0, value 0
    and noise 0; code 252 and every other pixel: weight 1. COLMAP's mask naming."""
    codes = np.full((2, 16, 16, 3), 120)
    codes[0, 1, 2, 0] = 255
    codes[0, 3, 4, 1] = 253
    codes[0, 5, 6, 2] = 252
    codes[0, 7, 8, 1] = 0
    for i in range(2):
        write_png8(tiny_scene / "images" / f"view_{i}.png", codes[i])
    mask = np.full((16, 16), 255)
    mask[10:12, 0:3] = 0
    write_png8(tiny_scene / "masks/view_1.png.png", mask)
    scene = load_scene(tiny_scene)
    expected = [np.ones((16, 16)), (mask > 0).astype(float)]
    expected[0][[1, 3, 7], [2, 4, 8]] = 0
    for i in range(2):
        name = f"view_{i}.png"
        assert np.array_equal(scene.weights[name], expected[i])
        assert (scene.images[name][expected[i] == 0] == 0).all()
        assert (scene.noise[name][expected[i] == 0] == 0).all()
        assert (scene.images[name][expected[i] == 1] > 0).all()
    # why: saturated (code 2: 255, 253 and the black-clipped 0), masked (code 1)
    reasons = np.zeros((16, 16), np.uint8)
    reasons[[1, 3, 7], [2, 4, 8]] = EXCLUSION_REASONS.index("saturated")
    assert np.array_equal(scene.excluded["view_0.png"], reasons)
    assert np.array_equal(scene.excluded["view_1.png"], np.where(mask > 0, 0, EXCLUSION_REASONS.index("mask")))
    assert scene.images["view_0.png"][5, 6, 2] == pytest.approx(srgb_decode(252 / 255), rel=1e-6)
    before = scene.content_hash
    mask[0, 0] = 0
    write_png8(tiny_scene / "masks/view_1.png.png", mask)
    assert load_scene(tiny_scene).content_hash != before
    edit_scene_yaml(tiny_scene, lambda d: d.update(photometry={"saturation": 0.5}))
    weights = load_scene(tiny_scene).weights
    assert weights["view_0.png"][5, 6] == 0 and weights["view_0.png"].sum() == 16 * 16 - 4
    edit_scene_yaml(tiny_scene, lambda d: d.update(photometry={"saturation": 0.45}))   # 120/255 = 0.47
    assert load_scene(tiny_scene).weights["view_0.png"].max() == 0


def test_undistortion_reads_the_photo_where_the_ray_meets_it(tmp_path):
    """A linear ramp over the delivered pixel grid (EXR): the loaded pinhole image is the ramp at
    the delivered position of each pixel's ray (bilinear interpolation is exact on a ramp); the
    pixels whose ray leaves the delivered image (pincushion corners), and those next to a masked
    pixel, weigh 0."""
    root = make_field_scene(tmp_path / "s", [("SIMPLE_RADIAL", {"coefficients": (0.12,)}), "OPENCV"], size=16)
    cams = load_scene(root).cameras
    ys, xs = np.mgrid[0:16, 0:16] + 0.5
    ramp = np.stack([0.1 + 0.01 * xs, 0.2 + 0.02 * ys, 0.05 + 0.01 * (xs + ys)], axis=-1)
    (root / "images").mkdir()
    for c in cams:
        write_exr(root / "images" / c.name.replace(".png", ".exr"), ramp)
    mask = np.full((16, 16), 255)
    mask[8, 8] = 0
    write_png8(root / "masks" / f"{cams[1].name}.png", mask)
    scene = load_scene(root)
    assert scene.noise is None
    for c in scene.cameras:
        delivered = c.delivered()
        at = np.asarray(delivered.img_from_cam(np.concatenate(
            [np.asarray(c.pinhole().cam_from_img(np.stack([xs.ravel(), ys.ravel()], 1))), np.ones((256, 1))], 1)))
        at = at.reshape(16, 16, 2)
        inside = ((at >= 0.5) & (at <= 15.5)).all(axis=2)
        expected = np.stack([0.1 + 0.01 * at[..., 0], 0.2 + 0.02 * at[..., 1],
                             0.05 + 0.01 * at.sum(axis=2)], axis=-1)
        weight = scene.weights[c.name] > 0
        np.testing.assert_allclose(scene.images[c.name][weight], expected[weight], atol=1e-6)
        assert (scene.images[c.name][~weight] == 0).all()
        reason = np.asarray(EXCLUSION_REASONS)[scene.excluded[c.name]]
        if c.distortion[0] == "SIMPLE_RADIAL":       # pincushion: the corners see outside the photo
            assert np.array_equal(weight, inside) and not weight[0, 0] and weight.mean() > 0.5
            assert set(reason[~weight]) == {"outside"} and set(reason[weight]) == {"used"}
        else:                                        # barrel: all inside, but for the masked pixel
            near = (np.abs(at - 8.5) < 1).all(axis=2)
            assert np.array_equal(weight, ~near) and near.sum() >= 1
            assert set(reason[near]) == {"mask"} and set(reason[~near]) == {"used"}


def _shifted_pinholes(dx: float, dy: float, size: int = 24):
    """A source and a target pinhole camera whose pixel grids differ by (dx, dy) source pixels:
    the target pixel centre (x, y) is the source position (x + dx, y + dy)."""
    import pycolmap
    make = lambda cx, cy: pycolmap.Camera(model="PINHOLE", width=size, height=size,  # noqa: E731
                                          params=[30.0, 30.0, cx, cy])
    return make(size / 2, size / 2), make(size / 2 - dx, size / 2 - dy)


@pytest.mark.parametrize("kernel, kept", [("bilinear", 0.5), ("cubic", 0.6875)])
def test_resampling_keeps_what_its_kernel_keeps_of_a_fine_pattern(kernel, kept):
    """A cosine of period 3 pixels moved by half a pixel: bilinear keeps cos(π/3) = 0.5 of its
    amplitude, cubic (Keys, a = -0.5: weights -1/16, 9/16, 9/16, -1/16 at the half pixel)
    2 (9/16 cos(π/3) - 1/16 cos(π)) = 0.6875; both by hand, asserted to 1e-12 away from the
    border."""
    source, target = _shifted_pinholes(0.5, 0.0)
    x = np.arange(24)[None, :].repeat(24, axis=0).astype(float)
    pattern = np.cos(2 * np.pi * x / 3)
    out, ok = Resampling(source=source, target=target, kernel=kernel).apply(pattern)
    expected = kept * np.cos(2 * np.pi * (x + 0.5) / 3)
    np.testing.assert_allclose(out[2:-3, 2:-3], expected[2:-3, 2:-3], atol=1e-12)
    assert ok[2:-3, 2:-3].all()


def test_cubic_resampling_is_exact_on_a_quadratic():
    """Keys' cubic convolution reproduces polynomials of degree 2 (third-order accurate), which
    bilinear interpolation does not: a quadratic surface moved by (0.3, 0.7) pixels, away from
    the border, to 1e-10."""
    source, target = _shifted_pinholes(0.3, 0.7)
    ys, xs = np.mgrid[0:24, 0:24].astype(float)
    f = lambda x, y: 0.2 + 0.01 * x + 0.003 * x * x - 0.002 * x * y + 0.004 * y * y  # noqa: E731
    cubic, _ = Resampling(source=source, target=target, kernel="cubic").apply(f(xs, ys))
    linear, _ = Resampling(source=source, target=target).apply(f(xs, ys))
    inner = (slice(2, -3), slice(2, -3))
    np.testing.assert_allclose(cubic[inner], f(xs + 0.3, ys + 0.7)[inner], atol=1e-10)
    assert np.abs(linear[inner] - f(xs + 0.3, ys + 0.7)[inner]).max() > 1e-4


def test_resampling_errors():
    source, target = _shifted_pinholes(0.5, 0.0)
    with pytest.raises(ValueError, match="kernel='lanczos': must be one of bilinear, cubic"):
        Resampling(source=source, target=target, kernel="lanczos")
    with pytest.raises(ValueError, match=r"pixels \[5, 3\) outside the target's 576"):
        Resampling(source=source, target=target).footprint(5, 3)
    with pytest.raises(ValueError, match=r"pixels \[0, 577\) outside the target's 576"):
        Resampling(source=source, target=target).footprint(0, 577)


def test_footprint_of_a_shift_is_the_shifted_source_pixels():
    """Grids shifted by (0.3, 0.7) source pixels (same focal length): a target pixel's footprint
    is the source pixels around its point, each a unit box (jacobian the identity), at the
    target's coordinates of their centres (the source centre minus the shift), weighted as the
    loader weighs them; by hand for the pixel (5, 4), centre (5.5, 4.5), the source point
    (5.8, 5.2): sources (5, 4), (6, 4), (5, 5), (6, 5), centres (5.5, 4.5) + offsets, at
    (5.2, 3.8) + offsets in the target, weights 0.7 · 0.3, 0.3 · 0.3, 0.7 · 0.7, 0.3 · 0.7."""
    source, target = _shifted_pinholes(0.3, 0.7)
    r = Resampling(source=source, target=target)
    fp = r.footprint()
    i = 4 * 24 + 5
    np.testing.assert_allclose(fp.position[i], [[5.2, 3.8], [6.2, 3.8], [5.2, 4.8], [6.2, 4.8]], atol=1e-9)
    np.testing.assert_allclose(fp.weight[i], [0.21, 0.09, 0.49, 0.21], atol=1e-12)
    np.testing.assert_allclose(fp.jacobian.reshape(-1, 4), np.tile([1.0, 0.0, 0.0, 1.0], (24 * 24, 1)), atol=1e-9)
    part = r.footprint(100, 130)
    np.testing.assert_array_equal(part.position, fp.position[100:130])
    np.testing.assert_array_equal(part.weight, fp.weight[100:130])
    outside = np.flatnonzero(~r.inside.ravel())
    assert outside.size and (fp.weight[outside, 0] == 1).all()
    np.testing.assert_allclose(fp.position[outside, 0], np.stack([outside % 24 + 0.5, outside // 24 + 0.5], 1))


@pytest.mark.parametrize("kernel", ["bilinear", "cubic"])
def test_footprint_centres_on_the_pixel_through_a_distorted_lens(kernel):
    """Through an OPENCV lens with fx != fy: the footprint's weighted centre is the target pixel's
    centre (interpolating the lens's mapping between source centres: second order, < 2e-3 px
    at this distortion, measured 1.3e-3), its weights the loader's, and a source pixel's sides
    in the target stretched by the focal lengths' ratio (f / fx along x, f / fy along y, within
    the lens's few % over the image)."""
    import pycolmap
    source = pycolmap.Camera(model="OPENCV", width=40, height=30,
                             params=[38.0, 36.0, 20.3, 14.8, -0.08, 0.01, 0.001, -0.002])
    target = pinhole_for(source)
    r = Resampling(source=source, target=target, kernel=kernel)
    fp = r.footprint()
    ok = r.inside.ravel()
    n = np.arange(40 * 30)
    centres = np.stack([n % 40 + 0.5, n // 40 + 0.5], axis=1)
    mean = (fp.weight[..., None] * fp.position).sum(axis=1)
    assert np.abs(mean - centres)[ok].max() < 2e-3
    np.testing.assert_allclose(fp.weight, np.stack([w.ravel() for _, _, w in r.taps], axis=1)
                               * ok[:, None] + np.eye(1, fp.weight.shape[1])[0] * ~ok[:, None], atol=1e-15)
    j = fp.jacobian[ok]
    assert np.abs(j[:, 0, 0] - 38.0 / 38.0).max() < 0.1 and np.abs(j[:, 1, 1] - 38.0 / 36.0).max() < 0.1
    assert np.abs(j[:, 0, 1]).max() < 0.05 and np.abs(j[:, 1, 0]).max() < 0.05


# ----------------------------------------------------------------------------------------------
# An undistorted synthetic photograph against the pinhole render
# ----------------------------------------------------------------------------------------------

REPLICATES = 8
SPP = 16


def _chain_weights(high: Camera, delivered, pinhole, valid: np.ndarray) -> np.ndarray:
    """alpha (H_h * W_h,): the mean over the ``valid`` pinhole pixels of resample(resample(x,
    high -> delivered), delivered -> pinhole) is alpha . x (the chain is linear; it is applied
    to the unit images of the high-resolution pixels, stacked as channels)."""
    n = high.width * high.height
    alpha = np.empty(n)
    for start in range(0, n, 512):
        stop = min(n, start + 512)
        unit = np.zeros((n, stop - start))
        unit[np.arange(start, stop), np.arange(stop - start)] = 1
        photo, _ = resample(unit.reshape(high.height, high.width, -1), source=high.pinhole(), target=delivered)
        back, _ = resample(photo, source=delivered, target=pinhole)
        alpha[start:stop] = back[valid].mean(axis=0)
    return alpha


@pytest.mark.slow
def test_undistorted_photo_equals_the_pinhole_render(tmp_path):
    """An OPENCV photograph (fx != fy) synthesised from a render at twice the resolution, written
    as a 16-bit sRGB PNG and loaded, equals a direct render of the loaded pinhole camera.

    The synthesis: the 64 x 64 pinhole camera ``high`` has twice the pinhole camera's f, cx, cy,
    so each pinhole pixel is exactly 2 x 2 of its pixels (box filters). ``high`` is rendered
    R = 8 times (16 spp, independent seeds), averaged (H), and resampled onto the delivered
    camera; pixels it cannot fill get code 0 (black-clipped, so the loader ignores what depends
    on them). The direct pinhole render P is R = 8 renders at other seeds.

    1. Decoding and undistortion: per pixel, the loaded image equals the test's own chain
       resample(resample(H, high -> delivered), delivered -> pinhole) within the 16-bit
       quantisation (half a code times the sRGB slope), since it is the same H.
    2. The mean difference d = mean over the weighted pixels of (loaded - P), per channel.
       Its variance follows from the per-pixel sample variances s^2 of the R renders: the
       direct pixels are independent, var = sum_p s_P^2 / (R n^2); the loaded mean is linear in
       the high-resolution pixels, alpha . H (alpha: :func:`_chain_weights`), var = sum_k alpha_k^2
       s_H,k^2 / R. The interpolation error is the difference of the two filters in expectation:
       E[d] = (alpha - beta) . E[H], with beta the 2 x 2 box average of the same pixels
       (beta_k = 1 / 4n); it is estimated as I = (alpha - beta) . H, with its own standard error
       from s_H (and must stay below 2 % of the mean radiance). Tolerance: |d| <= 4 SE(d) + |I| +
       4 SE(I) + the quantisation bound.
    """
    from framework.render.mitsuba_scene import MitsubaScene
    root = make_field_scene(tmp_path / "s", [("OPENCV", {"fx": 27.0, "fy": 29.5})], size=32, kernels=("diffuse",))
    written = distorted(load_scene(root).cameras[0], "OPENCV", fx=27.0, fy=29.5)   # what cameras.txt says
    delivered = written.delivered()
    pinhole = pinhole_for(delivered)
    f, cx, cy = pinhole.focal_length_x, pinhole.principal_point_x, pinhole.principal_point_y
    high = Camera("high.png", 64, 64, 2 * f, 2 * cx, 2 * cy, written.cam_from_world)
    synthetic = load_scene(root)                       # no images/: the references are known
    cam = synthetic.cameras[0]
    ms = MitsubaScene(synthetic, [high, cam], spp=SPP, integrator={"type": "path", "max_depth": 4})
    params = synthetic.parameters()
    ms.set_weights(synthetic.reference(params), params)
    highs = np.stack([ms.render(0, spp=SPP, seed=1 + 2 * r) for r in range(REPLICATES)]).astype(float)
    directs = np.stack([ms.render(1, spp=SPP, seed=1000 + 2 * r) for r in range(REPLICATES)]).astype(float)
    h_mean = highs.mean(0)

    photo, filled = resample(h_mean, source=high.pinhole(), target=delivered)
    codes = np.round(srgb_encode(np.clip(photo, 0, 1)) * 65535).astype(np.uint16)
    codes[~filled] = 0
    write_png16(root / "images" / cam.name, codes)
    scene = load_scene(root)
    loaded = scene.images[cam.name].astype(float)
    valid = scene.weights[cam.name] > 0
    assert 0.7 < valid.mean() < 1

    chain, ok = Resampling(source=delivered, target=pinhole).apply(photo, valid=filled)
    assert np.array_equal(ok, valid)
    quantisation = 0.5 / 65535 * _slope(np.minimum(srgb_encode(np.clip(chain, 0, 1)) + 1 / 65535, 1))
    assert (np.abs(loaded - chain)[valid] <= quantisation[valid] * (1 + 1e-3) + 1e-7).all()

    n = valid.sum()
    d = (loaded - directs.mean(0))[valid].mean(axis=0)
    var_direct = directs.var(0, ddof=1)[valid].sum(axis=0) / (REPLICATES * n ** 2)
    alpha = _chain_weights(high, delivered, pinhole, valid)
    beta = np.kron(valid.astype(float), np.ones((2, 2))).ravel() / (4 * n)
    s2_high = highs.var(0, ddof=1).reshape(-1, highs.shape[-1])
    se_d = np.sqrt(alpha ** 2 @ s2_high / REPLICATES + var_direct)
    interpolation = (alpha - beta) @ h_mean.reshape(-1, h_mean.shape[-1])
    se_i = np.sqrt((alpha - beta) ** 2 @ s2_high / REPLICATES)
    mean_radiance = directs.mean(0)[valid].mean(axis=0)
    assert (np.abs(interpolation) < 0.02 * mean_radiance).all(), (interpolation, mean_radiance)
    tolerance = 4 * se_d + np.abs(interpolation) + 4 * se_i + quantisation[valid].max()
    assert (np.abs(d) <= tolerance).all(), (d, se_d, interpolation, se_i)
