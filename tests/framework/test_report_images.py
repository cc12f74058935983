"""framework.images: EXR round trip, tone mapping, segment colours, image metrics."""
import math

import numpy as np
import pytest

from framework.images import (colorize_segments, image_metrics, read_exr, tonemap, write_exr,
                              write_png)


def test_exr_round_trip_rgb_and_mono(tmp_path):
    rng = np.random.default_rng(0)
    rgb = rng.uniform(0, 5, (32, 24, 3)).astype(np.float32)
    write_exr(tmp_path / "rgb.exr", rgb, ("R", "G", "B"))
    assert np.array_equal(read_exr(tmp_path / "rgb.exr"), rgb)
    mono = rng.uniform(0, 1, (8, 9)).astype(np.float32)
    write_exr(tmp_path / "y.exr", mono, ("Y",))
    back = read_exr(tmp_path / "y.exr")
    assert back.shape == (8, 9, 1) and back.dtype == np.float32
    assert np.array_equal(back[..., 0], mono)


@pytest.mark.parametrize("view", [lambda a: a[::-1], lambda a: a[:, ::-1],
                                  lambda a: a.transpose(1, 0, 2), lambda a: a[::2, 1::3],
                                  lambda a: a.astype(np.float64)])
def test_exr_non_contiguous_input_is_written_correctly(tmp_path, view):
    base = np.random.default_rng(1).uniform(0, 1, (32, 30, 3)).astype(np.float32)
    arr = view(base)
    write_exr(tmp_path / "nc.exr", arr, ("R", "G", "B"))
    assert np.array_equal(read_exr(tmp_path / "nc.exr"), arr.astype(np.float32))


def test_write_exr_checks_channel_names(tmp_path):
    with pytest.raises(ValueError, match="channels"):
        write_exr(tmp_path / "bad.exr", np.zeros((4, 4, 3)), ("Y",))
    with pytest.raises(FileNotFoundError):
        read_exr(tmp_path / "missing.exr")


def test_tonemap_auto_exposure_maps_p99_to_white():
    img = np.linspace(0, 2, 100 * 100, dtype=np.float32).reshape(100, 100)[..., None]
    out = tonemap(img)
    assert out.dtype == np.uint8 and out.shape == (100, 100, 3)
    assert out.max() == 255 and out[0, 0, 0] == 0
    p99 = np.percentile(img, 99)
    assert np.all(out[img[..., 0] < 0.99 * p99] < 255)
    assert tonemap(img, exposure=0.0).max() == 0


def test_write_png_rejects_float(tmp_path):
    with pytest.raises(ValueError, match="uint8"):
        write_png(tmp_path / "x.png", np.zeros((4, 4, 3)))
    write_png(tmp_path / "x.png", np.zeros((4, 4, 3), np.uint8))
    assert (tmp_path / "x.png").stat().st_size > 0


def test_colorize_segments():
    seg = np.array([[-1, 0], [1, 1]], np.int32)
    rgb = colorize_segments(seg, 2)
    assert rgb.shape == (2, 2, 3) and rgb.dtype == np.uint8
    assert tuple(rgb[0, 0]) == (40, 40, 40)
    assert tuple(rgb[0, 1]) != tuple(rgb[1, 0]) and tuple(rgb[1, 0]) == tuple(rgb[1, 1])
    with pytest.raises(ValueError, match="segment indices"):
        colorize_segments(seg, 1)


def test_metrics_constant_offset():
    obs = np.random.default_rng(2).uniform(0.2, 0.8, (32, 32, 3))
    offset = 0.05
    m = image_metrics(obs, obs + offset)
    data_range = obs.max() - obs.min()
    assert m["rmse"] == pytest.approx(offset, rel=1e-9)
    assert m["psnr"] == pytest.approx(20 * math.log10(data_range / offset), rel=1e-9)
    assert 0 < m["ssim"] < 1


def test_metrics_identical_and_small_images():
    obs = np.random.default_rng(3).uniform(0, 1, (16, 16))
    m = image_metrics(obs, obs)
    assert m["rmse"] == 0 and m["psnr"] == math.inf and m["ssim"] == pytest.approx(1.0)
    tiny = image_metrics(np.ones((2, 2, 3)), np.zeros((2, 2, 3)))
    assert tiny["rmse"] == 1 and math.isnan(tiny["ssim"])
    assert image_metrics(np.zeros((5, 5)), np.zeros((5, 5)) + 0.5)["ssim"] < 1
    with pytest.raises(ValueError, match="shapes differ"):
        image_metrics(np.zeros((8, 8, 3)), np.zeros((8, 8, 1)))
