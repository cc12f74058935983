"""Held-out views (issue 45, ``holdout=[...]``): refused names, metrics by hand, the prediction
at the estimate against the floor at the true reflectance, and every method with a view held out."""
from __future__ import annotations

import json

import numpy as np
import pytest
from factory import cli, compose_config, error_line, make_problem, make_tiny_scene, write_png8

from framework.errors import ConfigError
from framework.experiment import prepare, run_experiment
from framework.holdout_metrics import view_metrics
from framework.holdout_run import holdout_entries
from framework.registry import MethodResult, available_methods

FAST = ["render.spp=8", "observe.spp=32", "budget.renders=12", "report=false"]
METHOD_FAST = {"iterative": ["method.max_eval=2", "method.noise=fixed"], "differentiable": ["method.iterations=2"],
               "symbolic": ["method.solver.starts=1"], "lambertian_prior": ["method.solver.starts=1"]}
KEYS = {"view", "pixels", "rmse", "psnr", "psnr_srgb", "ssim", "z_rms", "segments"}


@pytest.fixture
def three_views(tmp_path):
    return make_tiny_scene(tmp_path / "tiny3", n_views=3)


def test_holdout_errors(three_views):
    """A name that is not a view, every view held out, a held-out view with no usable pixel."""
    with pytest.raises(ConfigError, match=r"^holdout names view_9.png, which is not a view of scene tiny: "
                                          r"name one of its views \(view_0.png, view_1.png, view_2.png\)$"):
        prepare(compose_config(three_views, "views=all", "holdout=[view_9.png]"))
    with pytest.raises(ConfigError, match=r"^holdout=\[view_0.png, view_1.png\] holds out every selected view"):
        prepare(compose_config(three_views, "views=[view_0.png,view_1.png]", "holdout=[view_0.png,view_1.png]"))
    with pytest.raises(ConfigError, match=r"^holdout lists view_1.png more than once"):
        prepare(compose_config(three_views, "views=all", "holdout=[view_1.png,view_1.png]"))
    for name in ("view_0.png", "view_1.png", "view_2.png"):
        write_png8(three_views / "images" / name, np.full((16, 16, 3), 120))
    write_png8(three_views / "masks/view_2.png.png", np.zeros((16, 16)))
    with pytest.raises(ConfigError, match=r"^holdout view view_2.png has no usable pixel \(every pixel masked, "
                                          r"saturated or black\), so there is nothing to compare"):
        prepare(compose_config(three_views, "views=all", "holdout=[view_2.png]"))


def test_holdout_error_on_the_command_line(three_views, tmp_path):
    """One line, status 2, no run folder left."""
    proc = cli([f"scene.dir={three_views}", "render.spp=4", "observe.spp=8", "report=false", "cache.dir=null",
                "views=all", "holdout=[view_9.png]", f"hydra.run.dir={tmp_path / 'run'}"], tmp_path)
    assert error_line(proc).startswith("error: holdout names view_9.png, which is not a view of scene tiny")
    assert not (tmp_path / "run").exists()


def test_held_out_view_is_not_fitted(three_views):
    problem, _, _ = prepare(compose_config(three_views, "views=all", "holdout=[view_2.png]"))
    assert [c.name for c in problem.cameras] == ["view_0.png", "view_1.png"]
    assert set(problem.observed) == {"view_0.png", "view_1.png"}
    assert [c.name for c in problem.held_out.cameras] == ["view_2.png"]
    assert problem.held_out.observed["view_2.png"].shape == (16, 16, 3)


def test_view_metrics_by_hand():
    """A prediction off by a known amount: RMSE is that amount, PSNR follows from the peak, z_rms
    is 1 when the variance is the squared offset; the masked pixel does not count."""
    obs = np.full((8, 8, 3), 0.5)
    obs[0, 0] = 0.8                                       # the peak
    pred = obs + np.array([0.01, 0.02, 0.04])
    used = np.ones((8, 8), bool)
    used[7, 7] = False
    pred[7, 7] = 5.0                                      # masked: must not count
    seg = np.zeros((8, 8), int)
    seg[:, 4:] = 1
    m = view_metrics(obs, pred, used, seg, ["a", "b"], variance=np.broadcast_to([1e-4, 4e-4, 16e-4], obs.shape))
    assert m["pixels"] == 63
    np.testing.assert_allclose(m["rmse"], [0.01, 0.02, 0.04], rtol=1e-9)
    mse = (0.01 ** 2 + 0.02 ** 2 + 0.04 ** 2) / 3
    assert m["psnr"] == pytest.approx(10 * np.log10(0.8 ** 2 / mse), rel=1e-9)
    assert m["z_rms"] == pytest.approx(1.0, rel=1e-9)
    assert 0 < m["ssim"] < 1 and 0 < m["psnr_srgb"]
    assert set(m["segments"]) == {"a", "b"} and m["segments"]["a"]["pixels"] == 32
    assert m["segments"]["b"]["pixels"] == 31
    same = view_metrics(obs, obs, used, seg, ["a", "b"])
    assert same["psnr"] is None and same["ssim"] == pytest.approx(1.0) and same["z_rms"] is None


def test_symbolic_prediction_against_the_floor(tmp_path):
    """The default method on two views of a diffuse scene predicts the third: the floor (the
    true reflectance's prediction) has the residuals of the Monte Carlo noise alone (RMS z 1), and
    the estimate's RMSE is within 1.1x of it with an honest image-space std (measured: 1.02x,
    RMS z 1.03; floor RMS z 1.05)."""
    root = make_tiny_scene(tmp_path / "tiny3", n_views=3, kernels=("diffuse",))
    cfg = compose_config(root, "views=all", "holdout=[view_2.png]", "observe.spp=256", "render.spp=32",
                         "report=false", f"cache.dir={tmp_path / 'cache'}")
    results = run_experiment(cfg, tmp_path / "run")
    (entry,) = json.loads((tmp_path / "run/results.json").read_text())["holdout"]
    assert results["settings"]["holdout"] == ["view_2.png"] and results["settings"]["views"] == ["view_0.png",
                                                                                                 "view_1.png"]
    assert set(entry) >= KEYS | {"floor", "images"} and entry["view"] == "view_2.png"
    assert set(entry["segments"]) == {"ground", "block"}
    floor, ours = np.array(entry["floor"]["rmse"]), np.array(entry["rmse"])
    assert np.all(ours < 1.1 * floor)
    assert 0.7 < entry["floor"]["z_rms"] < 1.5 and 0.7 < entry["z_rms"] < 1.5
    assert (tmp_path / "run" / entry["images"]["prediction"]).is_file()


@pytest.mark.parametrize("method", available_methods())
def test_every_method_runs_with_a_view_held_out(method, tiny_scene, tmp_path):
    """Each registered method, fitted on view_0, predicts view_1 and reports its metrics."""
    cfg = compose_config(tiny_scene, "views=all", "holdout=[view_1.png]", f"method={method}",
                         f"cache.dir={tmp_path / 'cache'}", *FAST, *METHOD_FAST.get(method, []))
    results = run_experiment(cfg, tmp_path / "run")
    (entry,) = results["holdout"]
    assert set(entry) >= KEYS and entry["view"] == "view_1.png" and entry["pixels"] == 256
    assert len(entry["rmse"]) == 3 and all(np.isfinite(entry["rmse"]))
    assert results["settings"]["views"] == ["view_0.png"]


def test_image_space_std_carries_the_parameters_covariance(tmp_path):
    """Every weight 0.1 off its reference: with a std of 0.1 on each weight the residuals are
    about one predicted std (the delta method through each pixel), with no std (a baseline)
    many times the noise alone (measured: RMS z 0.80 and 3.71)."""
    root = make_tiny_scene(tmp_path / "tiny3", n_views=3, kernels=("diffuse",))
    problem = make_problem(root, None, "holdout=[view_2.png]", "observe.spp=256", "render.spp=32")
    ref = problem.scene.reference(problem.parameters)
    z = {}
    for label, std in (("std", np.full_like(ref, 0.1)), ("none", None)):
        result = MethodResult(estimate=ref + 0.1, renders=0, std=std)
        (entry,) = holdout_entries(problem, result, problem.held_out)
        z[label] = entry["z_rms"]
    assert 0.6 < z["std"] < 1.5 and z["none"] > 3.0, z


def test_held_out_gain_and_falloff(three_views):
    """A held-out view's gain is 1 when the method estimated none, else its least-squares fit
    to the photograph over the used pixels, per channel (by hand: a photograph 2, 0.5 and 1.25
    times the prediction, where used, gives those gains; a dark channel 1); and its lens's falloff
    1 + a1 r² + a2 r⁴ + a3 r⁶ (r = 1 at the image corner)."""
    import dataclasses

    from framework.holdout import held_out_gain, lens_falloff
    from framework.scene import load_scene
    from framework.scene.model import Photometry
    rng = np.random.default_rng(0)
    prediction = rng.uniform(0.1, 1.0, (4, 5, 3))
    used = np.ones((4, 5), bool)
    used[0] = False
    observed = prediction * [2.0, 0.5, 1.25]
    observed[0] = 9.0                                             # not used: no weight in the fit
    exposure = {"exposure": [{"view": "a", "estimate": [1.0, 1.0, 1.0]}]}
    np.testing.assert_allclose(held_out_gain(exposure, observed, prediction, used), [2.0, 0.5, 1.25])
    np.testing.assert_array_equal(held_out_gain({}, observed, prediction, used), [1.0, 1.0, 1.0])
    dark = prediction * [1.0, 0.0, 1.0]
    assert held_out_gain(exposure, observed, dark, None)[1] == 1.0
    scene = load_scene(three_views)
    lens = dataclasses.replace(scene, photometry=Photometry(vignetting="known", vignetting_profile=(-0.3, 0.1, -0.05)))
    cam = scene.camera("view_2.png")
    assert lens_falloff(scene, cam, {}) == 1.0
    v = lens_falloff(lens, cam, {})[..., 0]
    corner = np.hypot(cam.width / 2 - 0.5, cam.height / 2 - 0.5) / (0.5 * np.hypot(cam.width, cam.height))
    r2 = corner ** 2
    assert v[0, 0] == pytest.approx(1 - 0.3 * r2 + 0.1 * r2 ** 2 - 0.05 * r2 ** 3, rel=1e-9)
    estimated = {"vignetting": [{"camera": str(cam.camera_id), "estimate": [-0.5, 0.0, 0.0]}]}
    assert lens_falloff(lens, cam, estimated)[0, 0, 0] == pytest.approx(1 - 0.5 * r2, rel=1e-9)


@pytest.mark.parametrize("kernel", ["bilinear", "cubic"])
def test_prediction_integrates_the_resampling_footprint(tmp_path, kernel):
    """A resampled view's prediction is the footprint's weighted sum of source-pixel means: on a
    fine image linear in the pinhole coordinates (whose box means are its centre values, and
    which bilinear reads exactly) it is sum_k w_k f(position_k), by hand."""
    from factory import make_field_scene

    from framework.holdout_footprint import integrate
    from framework.scene import load_scene
    from framework.scene.undistort import Resampling
    cam = load_scene(make_field_scene(tmp_path / "field", [("OPENCV", {"fx": 26.0, "fy": 29.5})], size=32)).cameras[0]
    footprint = Resampling(source=cam.delivered(), target=cam.pinhole(), kernel=kernel).footprint()
    s = 4
    ys, xs = np.mgrid[0:cam.height * s, 0:cam.width * s] + 0.5
    fine = np.stack([0.3 * xs / s + 0.1 * ys / s + 2.0, np.ones_like(xs)], axis=-1)
    out = integrate(fine, footprint, cam, s).reshape(-1, 2)
    p = footprint.position
    by_hand = np.einsum("nk,nk->n", footprint.weight, 0.3 * p[..., 0] + 0.1 * p[..., 1] + 2.0)
    inner = np.all((p > 1.5) & (p < np.array([cam.width, cam.height]) - 1.5), axis=(1, 2))
    assert inner.sum() > 500
    np.testing.assert_allclose(out[inner, 0], by_hand[inner], rtol=1e-5)
    np.testing.assert_allclose(out[:, 1], 1.0, rtol=1e-5)
    assert np.ptp(footprint.jacobian[inner]) > 0.01 and footprint.weight.max() < 1     # not the identity


def test_held_out_light_at_the_estimated_scale(three_views):
    """An emitter of unknown scale shines at the scale the fit estimated; the others as declared."""
    from factory import edit_scene_yaml

    from framework.holdout import estimated_light
    from framework.scene import load_scene
    edit_scene_yaml(three_views, lambda d: d["emitters"][0].update(scale="unknown"))
    scene = load_scene(three_views)
    lit = estimated_light(scene, {"illumination": [{"emitter": 0, "part": None, "estimate": [2.0, 1.0, 0.5]}]})
    np.testing.assert_allclose(lit.emitters[0].radiance, scene.emitters[0].radiance * [2.0, 1.0, 0.5])
    np.testing.assert_array_equal(lit.emitters[1].irradiance, scene.emitters[1].irradiance)
    assert lit.content_hash != scene.content_hash
    assert estimated_light(scene, {"illumination": [{"emitter": 0, "part": None, "estimate": None}]}) is scene


def test_fit_noise_less_the_reconstructions_own_variance(three_views):
    """The photographs' noise the fit saw, in unit-gain radiance: the fitted views' mean squared
    residual over their gains, less the reconstructions' Monte Carlo variance where the method
    reports it, floored at 0 (by hand: residual 0.02 everywhere, squared 4e-4; less 1e-4 is 3e-4;
    less 5e-4 is 0)."""
    from framework.holdout_run import fit_noise
    problem = make_problem(three_views)
    recon = {c.name: problem.observed[c.name] + 0.02 for c in problem.cameras}
    bare = MethodResult(estimate=np.zeros((1, 3)), renders=0, reconstructions=recon)
    np.testing.assert_allclose(fit_noise(problem, bare), 4e-4, rtol=1e-5)
    for var, noise in ((1e-4, 3e-4), (5e-4, 0.0)):
        own = {name: np.full_like(img, var) for name, img in recon.items()}
        result = MethodResult(estimate=np.zeros((1, 3)), renders=0, reconstructions=recon,
                              reconstruction_variance=own)
        np.testing.assert_allclose(fit_noise(problem, result), noise, rtol=1e-4, atol=1e-12)
    # in unit-gain radiance: a view of gain 2 has residual 0.01 there, squared 1e-4; (1 + 4 + 4) / 3
    first = problem.cameras[0].name
    gained = MethodResult(estimate=np.zeros((1, 3)), renders=0, reconstructions=recon,
                          extras={"exposure": [{"view": first, "estimate": [2.0, 2.0, 2.0]}]})
    np.testing.assert_allclose(fit_noise(problem, gained), 3e-4, rtol=1e-5)
