"""Relighting and reflectance images (framework.relight) on the tiny diffuse scene."""
from __future__ import annotations

import pytest

import numpy as np
from factory import edit_scene_yaml, make_problem, make_tiny_scene, mean_difference, run_symbolic

from framework.relight import reflectance_images, relit_scene, render_relit, sun
from framework.scene import load_scene

NEW_SUN = [-0.5, 0.2, -0.84]


def _scene(tmp_path):
    return load_scene(make_tiny_scene(tmp_path / "s", kernels=("diffuse",)))


def test_relit_scene_replaces_illumination(tmp_path):
    scene = _scene(tmp_path)
    new = relit_scene(scene, [sun(NEW_SUN, 2.0, scene.channels)])
    assert [e.type for e in new.emitters] == ["directional"]
    np.testing.assert_allclose(np.linalg.norm(new.emitters[0].direction), 1.0)
    np.testing.assert_allclose(new.emitters[0].irradiance, [2.0, 2.0, 2.0])
    assert new.content_hash != scene.content_hash and new.meshes == scene.meshes


@pytest.mark.slow
def test_relit_matches_path_render_of_relit_scene_folder(tmp_path):
    """At the true weights, relighting equals Mitsuba ``path`` on a scene folder written with the
    new sun. Both are Monte Carlo: 8 seeded repetitions at 16 spp each give per-pixel means and
    sample variances; the channel means over the image agree within 4σ (σ from the per-pixel
    variances), and ≥ 99 % of pixels agree within 4σ (per pixel); the relit image is also
    significantly different (> 4σ) from the original illumination on > 2 % of pixel channels.
    The 4σ bounds are z-tests; the power threshold 2 % was checked over 6 seed sets (seeds
    16j + 0..15, j = 0-5; the test uses j = 0): 4.0-4.7 % of pixel channels, and the fraction
    within 4σ of the truth was 99.6-100 %."""
    scene = _scene(tmp_path)
    params = scene.parameters()
    rho = scene.reference(params)
    edit_scene_yaml(scene.root, lambda d: d["emitters"][1].update(direction=NEW_SUN))
    truth_scene = load_scene(scene.root)
    relit = relit_scene(scene, [e for e in scene.emitters if e.type == "constant"]
                        + [sun(NEW_SUN, scene.emitters[1].irradiance, scene.channels)])
    cam = [scene.cameras[0]]
    a = np.stack([render_relit(relit, cam, rho, params, spp=16, seed=2 * k)[cam[0].name] for k in range(8)])
    b = np.stack([render_relit(truth_scene, cam, rho, params, spp=16, seed=2 * k + 1)[cam[0].name]
                  for k in range(8)])
    diff, se = mean_difference(a, b)
    var = se ** 2
    n = var[..., 0].size
    assert np.all(np.abs(diff.mean((0, 1))) <= 4 * np.sqrt(var.sum((0, 1))) / n)
    z = np.abs(diff) / np.maximum(se, 1e-6)
    assert np.mean(z <= 4) >= 0.99
    orig = np.stack([render_relit(scene, cam, rho, params, spp=16, seed=2 * k)[cam[0].name] for k in range(8)])
    diff0, se0 = mean_difference(a, orig)
    z0 = np.abs(diff0) / np.maximum(se0, 1e-6)
    assert np.mean(z0 > 4) > 0.02     # null rate ~0.1 % (t, 14 dof); the moved sun moves shadows


def test_reflectance_image_is_segment_weight(tmp_path):
    """Each pixel holds the diffuse weight of the segment it sees; sky pixels 0; NaN weights stay NaN."""
    from framework.render.mitsuba_scene import MitsubaScene
    scene = _scene(tmp_path)
    params = scene.parameters()
    rho = np.array([[0.1, 0.2, 0.3], [np.nan, 0.5, 0.6]])
    cam = scene.cameras[0]
    img = reflectance_images(scene, [cam], rho, params)[cam.name]
    seg = MitsubaScene(scene, [cam], spp=1).segment_map(0)
    assert img.shape == (cam.height, cam.width, 3)
    np.testing.assert_allclose(img[seg == 0], np.broadcast_to([0.1, 0.2, 0.3], img[seg == 0].shape), rtol=1e-6)
    assert np.isnan(img[seg == 1][:, 0]).all() and np.allclose(img[seg == 1][:, 1], 0.5)
    assert (img[seg == -1] == 0).all()
    assert (seg == 0).any() and (seg == 1).any()


@pytest.mark.slow
def test_symbolic_relight_option(tmp_path):
    """``method.relight.enabled`` puts ``<view>.relit`` and ``<view>.reflectance`` arrays into
    extras["relit_images"] and times them."""
    problem = make_problem(make_tiny_scene(tmp_path / "s", kernels=("diffuse",)))
    res = run_symbolic(problem, relight={"enabled": True, "sun_direction": NEW_SUN, "spp": 4,
                                         "sun_irradiance": None, "sky_radiance": None, "reflectance": "diffuse"})
    images = res.extras["relit_images"]
    assert sorted(images) == ["view_0.png.reflectance", "view_0.png.relit",
                              "view_1.png.reflectance", "view_1.png.relit"]
    assert all(v.shape == (16, 16, 3) for v in images.values())
    assert "relight" in res.timings_s
