"""A run that cannot do what was asked says so (issue 28): inputs that used to exit 0 with results
nobody intended, or end in a traceback, now get one line ``error: ...`` (exit 2, nothing left
behind) or a warning that says what was left out. One test per case, on the tiny scenes of
factory.py; the command-line cases through ``python -m framework.run`` in a subprocess."""
from __future__ import annotations

import json
import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from factory import (cli, compose_config, edit_scene_yaml, error_line, make_field_scene, make_tiny_scene,
                     scene_error_message, write_png8)

import framework.run
from framework.errors import ConfigError, SceneError
from framework.experiment import prepare
from framework.scene import load_scene
from framework.scene.write import pinhole_camera, write_colmap
from scenes.cameras import look_at

TINY = ["render.spp=4", "observe.spp=8", "report=false"]
GREY = 120          # an 8-bit code well inside the usable range (not black, not saturated)




def _photos(root: Path, codes: dict[str, int]) -> None:
    """Uniform 16x16 8-bit photographs: view name -> code."""
    for name, code in codes.items():
        write_png8(root / "images" / name, np.full((16, 16, 3), code))


def _sky_view(root: Path) -> Path:
    """Replace view_1 of a tiny scene by a camera looking straight up: it sees only sky."""
    f = 16 / (2 * np.tan(np.radians(30)))
    shutil.rmtree(root / "sparse")
    write_colmap(root / "sparse", [pinhole_camera("view_0.png", 16, 16, f, look_at([6, -5, 4], [0, 0, 0.8])),
                                   pinhole_camera("view_1.png", 16, 16, f, look_at([0, 0, 10], [0.01, 0, 20]))])
    return root


# ----------------------------------------------------------------------------------------------
# 1. Photographs with no usable pixel; 18. one rule for photographs and synthetic observations
# ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("case", ["black", "saturated", "mask"])
def test_view_without_usable_pixel_is_an_error(tiny_scene, case):
    """One view whose every pixel is black, saturated or masked: nothing to fit (was: exit 0,
    every estimate null, ill_determined false)."""
    _photos(tiny_scene, {"view_0.png": {"black": 0, "saturated": 255, "mask": GREY}[case], "view_1.png": GREY})
    if case == "mask":
        write_png8(tiny_scene / "masks/view_0.png.png", np.zeros((16, 16)))
    with pytest.raises(SceneError) as info:
        prepare(compose_config(tiny_scene, "views=[view_0.png]"))
    assert str(info.value) == ("no selected view has a usable pixel (view_0.png: every pixel masked, saturated "
                               "or black): nothing to fit; fix the photographs or masks, or select other views "
                               "(views=...)")


@pytest.mark.slow
def test_view_without_usable_pixel_is_left_out(tiny_scene, tmp_path, caplog):
    """With another usable view: a warning, the view left out of the fit and named in
    results.json ``views_left_out``; the estimates come from the other view."""
    _photos(tiny_scene, {"view_0.png": 0, "view_1.png": GREY})
    with caplog.at_level(logging.WARNING, logger="framework.render.checks"):
        problem, _, _ = prepare(compose_config(tiny_scene, "views=all"))
    assert [c.name for c in problem.cameras] == ["view_1.png"]
    assert problem.views_left_out == {"view_0.png": "has no usable pixel (every pixel masked, saturated or black)"}
    assert ("view view_0.png has no usable pixel (every pixel masked, saturated or black): it constrains no "
            "parameter and is left out of the fit") in caplog.text
    proc = cli([f"scene.dir={tiny_scene}", *TINY, f"hydra.run.dir={tmp_path / 'run'}", "cache.dir=null"], tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    results = json.loads((tmp_path / "run/results.json").read_text())
    assert results["views_left_out"] == [{"name": "view_0.png", "reason": "has no usable pixel (every pixel "
                                                                          "masked, saturated or black)"}]
    assert results["settings"]["views"] == ["view_1.png"]


def test_reference_view_left_out_errors(tiny_scene):
    """A per-view exposure's reference view without a usable pixel: the error says it was left out
    and why (was: "reference_view view_0.png is not among this run's views", though it was selected)."""
    _photos(tiny_scene, {"view_0.png": GREY, "view_1.png": GREY})
    write_png8(tiny_scene / "masks/view_0.png.png", np.zeros((16, 16)))
    edit_scene_yaml(tiny_scene, lambda d: d.update(photometry={"exposure": "per_view", "reference_view": "view_0.png"}))
    with pytest.raises(ConfigError, match=r"^photometry reference_view view_0.png was left out of this run: it has "
                       r"no usable pixel \(every pixel masked, saturated or black\), so its gains cannot be the "
                       r"fit's reference; name another view as reference_view in scene.yaml \(view_1.png\), fix "
                       r"its photograph or mask, or set method.exposure=known$"):
        prepare(compose_config(tiny_scene, "views=all"))


@pytest.mark.slow
def test_sky_only_view_one_rule(tmp_path):
    """A view whose usable pixels see only sky: the same for photographs (its segment pixels
    masked) as for synthetic observations of a camera facing the sky. Alone: the same error
    (the photographs ran with exit 0 before); with a view that sees: left out, said."""
    synthetic = _sky_view(make_tiny_scene(tmp_path / "synthetic"))
    photo = make_tiny_scene(tmp_path / "photo")
    _photos(photo, {"view_0.png": GREY, "view_1.png": GREY})
    seen = load_scene(photo)
    from framework.render.mitsuba_scene import MitsubaScene
    segments = MitsubaScene(seen, [seen.camera("view_1.png")], spp=1).segment_map(0)
    assert (segments >= 0).any() and (segments < 0).any()         # it sees the scene and some sky
    write_png8(photo / "masks/view_1.png.png", np.where(segments >= 0, 0, 255))
    for scene, where in ((synthetic, ""), (photo, " in their usable pixels")):
        with pytest.raises(SceneError) as info:
            prepare(compose_config(scene, "views=[view_1.png]"))
        assert str(info.value) == (f"no selected view sees any segment (view_1.png see only sky or nothing{where}): "
                                   f"fix their poses in {scene / 'sparse'} or select other views (views=...)")
        problem, _, _ = prepare(compose_config(scene, "views=all"))
        assert [c.name for c in problem.cameras] == ["view_0.png"]
        assert problem.views_left_out == {"view_1.png": "sees no segment (only sky or nothing)"
                                          + (" in its usable pixels" if scene == photo else "")}


# ----------------------------------------------------------------------------------------------
# 2. Mask spellings, unused files
# ----------------------------------------------------------------------------------------------

def test_plain_mask_name_is_read(tiny_scene):
    """``masks/view_1.png`` (named like its image) masks view_1.png as COLMAP's
    ``masks/view_1.png.png`` does (was: silently ignored)."""
    _photos(tiny_scene, {"view_0.png": GREY, "view_1.png": GREY})
    mask = np.full((16, 16), 255)
    mask[:4] = 0
    write_png8(tiny_scene / "masks/view_1.png", mask)
    weights = load_scene(tiny_scene).weights
    assert np.array_equal(weights["view_1.png"], (mask > 0).astype(np.float32))
    write_png8(tiny_scene / "masks/view_1.png.png", mask)
    scene_error_message(tiny_scene, r"masks/view_1.png.png and .*masks/view_1.png: two masks for image view_1.png "
                                    r"\(COLMAP's name <image>.png and the plain one\); keep one, delete the other$")


def test_unused_files_are_named(tiny_scene, caplog):
    """A mask and an image that no view reads: a warning naming each."""
    _photos(tiny_scene, {"view_0.png": GREY, "view_1.png": GREY, "view_9.png": GREY})
    write_png8(tiny_scene / "masks/view_0.jpg.png", np.full((16, 16), 255))
    with caplog.at_level(logging.WARNING, logger="framework.scene.photos"):
        load_scene(tiny_scene)
    assert (f"{tiny_scene.resolve()}: images/view_9.png not read by any view of the COLMAP model (a view reads "
            "images/<image name> or images/<image stem>.exr); rename or remove it") in caplog.text
    assert "masks/view_0.jpg.png not read by any view" in caplog.text


# ----------------------------------------------------------------------------------------------
# 3. A method.kernels entry on no segment
# ----------------------------------------------------------------------------------------------

def test_kernel_on_no_segment(tmp_path):
    """``glossy(0.3)`` on a scene whose segments have ``glossy(0.2)``: refused, listing the
    scene's kernels (was: dropped, its light going into ρ_d)."""
    scene = make_tiny_scene(tmp_path / "tiny", kernels=("diffuse",))

    def glossy(desc):
        for s in desc["segments"]:
            s["kernels"].append("glossy(0.2)")
            s["reference"]["glossy(0.2)"] = [0.1, 0.1, 0.1]
    edit_scene_yaml(scene, glossy)
    with pytest.raises(ConfigError) as info:
        prepare(compose_config(scene, 'method.kernels=[diffuse,"glossy(0.3)"]'))
    assert str(info.value) == ("method.kernels lists glossy(0.3), which no segment of scene tiny has (its kernels: "
                               "diffuse, glossy(0.2)): list only the scene's kernels, or use all")


# ----------------------------------------------------------------------------------------------
# 4, 15. A distortion that folds the image; every image of the camera named
# ----------------------------------------------------------------------------------------------

def test_folding_distortion(tmp_path):
    """SIMPLE_RADIAL k = -5 on a 16x16 camera of f = 13.9: d(r) = r (1 - 5 r^2) peaks at
    r = 1/sqrt(15), d = 0.172, short of the corner's normalised radius 8 sqrt(2) / 13.9 = 0.815.
    Both images share the camera: both are named. k = -0.08 (the field tests') stays accepted."""
    root = make_field_scene(tmp_path / "fold", ("SIMPLE_RADIAL", "SIMPLE_RADIAL"))
    lines = (root / "sparse/cameras.txt").read_text().splitlines()
    lines = [ln for ln in lines if not ln.startswith("2 ")]
    lines = [" ".join(ln.split()[:-1] + ["-5"]) if ln.startswith("1 ") else ln for ln in lines]
    (root / "sparse/cameras.txt").write_text("\n".join(lines) + "\n")
    images = (root / "sparse/images.txt").read_text().splitlines()
    images = [" ".join(f[:8] + ["1"] + f[9:]) if len(f := ln.split()) == 10 and not ln.startswith("#") else ln
              for ln in images]
    (root / "sparse/images.txt").write_text("\n".join(images) + "\n")
    for name in ("rigs.txt", "frames.txt"):            # the poses from images.txt alone
        (root / "sparse" / name).unlink(missing_ok=True)
    msg = scene_error_message(root, r"cameras.txt: camera 1 \(of images view_0.png, view_1.png\): its SIMPLE_RADIAL "
                                    r"distortion \(k=-5\) folds the image: the distorted radius stops growing at "
                                    r"0.172 \(normalised\), short of the 0.8\d+ of the image's farthest corner")
    assert msg.endswith("fix the calibration (the sign or size of the coefficients)")
    load_scene(make_field_scene(tmp_path / "ok", ("SIMPLE_RADIAL", "SIMPLE_RADIAL")))


# ----------------------------------------------------------------------------------------------
# 6. image_rmse over the pixels the fit used
# ----------------------------------------------------------------------------------------------

def test_image_rmse_counts_used_pixels_only():
    """Half a view masked (observation 0 there, weight 0): the RMSE is that of the other half
    (was: the masked half counted against the zeroed observations). Exact arithmetic."""
    from types import SimpleNamespace

    from framework.registry import MethodResult
    from framework.results import image_rmse
    obs = np.full((4, 4, 3), 0.5, np.float32)
    weights = np.ones((4, 4), np.float32)
    weights[:2] = 0
    obs[:2] = 0.0
    rec = np.full((4, 4, 3), 0.6, np.float32)
    problem = SimpleNamespace(observed={"v": obs}, weights={"v": weights})
    result = MethodResult(estimate=np.zeros((1, 3)), renders=1, reconstructions={"v": rec})
    assert image_rmse(problem, result) == pytest.approx(0.1, rel=1e-6)     # float32 inputs
    result.pixel_weights = {"v": np.where(np.arange(4)[None, :] < 3, 1.0, 0.0) * np.ones((4, 4))}
    rec[2:, 3] = 5.0                         # a pixel the fit left out (weight 0) does not count
    assert image_rmse(problem, result) == pytest.approx(0.1, rel=1e-6)


# ----------------------------------------------------------------------------------------------
# 7, 8, 9. Tracebacks: executor address, run-folder path length, image name length
# ----------------------------------------------------------------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("address, message", [
    ("garbage", "executor.address=garbage is not a scheduler address: write tcp://host:port (the scheduler's "
                "address, port 8786 by default), or executor.address=null"),
    ("http://localhost:8787", "executor.address=http://localhost:8787: the scheme http:// is not one a Dask "
                              "scheduler listens on (tcp://, tls://): write tcp://host:port"),
    ("tcp://localhost", "executor.address=tcp://localhost lacks a host and a port number (1-65535)"),
])
def test_executor_address_form(tiny_scene, tmp_path, address, message):
    proc = cli([f"scene.dir={tiny_scene}", *TINY, "executor=dask", f"executor.address={address}",
                 f"hydra.run.dir={tmp_path / 'run'}", "cache.dir=null"], tmp_path)
    assert error_line(proc).startswith(f"error: {message}")
    assert not (tmp_path / "run").exists()


@pytest.mark.slow
def test_run_folder_name_too_long(tiny_scene, tmp_path):
    """A part of 300 bytes: one line, and no folder created (was: three chained tracebacks and
    an empty parent folder)."""
    run_dir = tmp_path / "parent" / ("x" * 300)
    proc = cli([f"scene.dir={tiny_scene}", *TINY, f"hydra.run.dir={run_dir}", "cache.dir=null"], tmp_path)
    assert error_line(proc).endswith(f"(hydra.run.dir): its part '{'x' * 37}...' is 300 bytes, more than the 255 "
                                      "this file system allows in one name: choose a shorter hydra.run.dir")
    assert not (tmp_path / "parent").exists()
    deep = tmp_path / "/".join(["d" * 200] * 21)                  # 4200 bytes > PATH_MAX
    proc = cli([f"scene.dir={tiny_scene}", *TINY, f"hydra.run.dir={deep}", "cache.dir=null"], tmp_path)
    assert "this file system allows in a path: choose a shorter hydra.run.dir" in error_line(proc)
    assert not (tmp_path / ("d" * 200)).exists()


@pytest.mark.slow
def test_image_name_too_long(tmp_path):
    """A 249-byte COLMAP image name: refused before anything is rendered (was: the run computed
    everything, then failed writing its images)."""
    name = "v" * 245 + ".png"
    root = make_tiny_scene(tmp_path / "long", n_views=1)
    images = root / "sparse/images.txt"
    images.write_text(images.read_text().replace("view_0.png", name))
    proc = cli([f"scene.dir={root}", *TINY, f"hydra.run.dir={tmp_path / 'run'}", "cache.dir=null"], tmp_path)
    assert error_line(proc).startswith(f"error: image name '{name[:40]}...' (249 bytes) is too long for the files "
                                        "the run names after it")
    assert not (tmp_path / "run").exists()


# ----------------------------------------------------------------------------------------------
# 10, 16. Messages
# ----------------------------------------------------------------------------------------------

def test_blank_segment_name(tiny_scene):
    edit_scene_yaml(tiny_scene, lambda d: d["segments"][0].update(name=" "))
    scene_error_message(tiny_scene, r"scene.yaml: segment ' ' name must be a non-empty string; got a blank string "
                                    r"\(1 whitespace character, ' '\): give it a name$")


def test_article_before_camera_model():
    from framework.scene.colmap import article
    assert [f"{article(m)} {m}" for m in ("OPENCV", "SIMPLE_RADIAL", "RADIAL", "OPENCV_FISHEYE")] == [
        "an OPENCV", "a SIMPLE_RADIAL", "a RADIAL", "an OPENCV_FISHEYE"]


# ----------------------------------------------------------------------------------------------
# 11, 12. Interrupted set-up, the cache folder a failed run created
# ----------------------------------------------------------------------------------------------

@pytest.mark.slow
def test_interrupt_during_mitsuba_start(tiny_scene, tmp_path):
    """Ctrl-C while Mitsuba starts, which a library reports as an error: ``interrupted``, exit
    130 (was: "variant=llvm_ad_rgb cannot start on this machine", exit 2). The interrupt is
    simulated where it happens: SIGINT delivered inside ``mitsuba.set_variant``, which turns it
    into a RuntimeError as Dr.Jit does."""
    script = (
        "import os, signal, mitsuba\n"
        "def interrupted(*a, **k):\n"
        "    try:\n"
        "        os.kill(os.getpid(), signal.SIGINT)\n"
        "    except KeyboardInterrupt:\n"
        "        raise RuntimeError('KeyboardInterrupt during initialisation')\n"
        "mitsuba.set_variant = interrupted\n"
        "import sys\n"
        "from framework.run import cli\n"
        f"sys.argv[1:] = {[f'scene.dir={tiny_scene}', *TINY, 'hydra.run.dir=' + str(tmp_path / 'run'), 'cache.dir=' + str(tmp_path / 'cache')]!r}\n"
        "cli()\n")
    env = dict(os.environ, PYTHONPATH=str(Path(framework.run.__file__).parents[1]))
    proc = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 130, proc.stderr[-2000:]
    assert [line for line in proc.stderr.splitlines() if line.strip()][-1] == "interrupted"
    assert not (tmp_path / "run").exists() and not (tmp_path / "cache").exists()


@pytest.mark.slow
def test_failed_run_removes_the_cache_folder_it_created(tmp_path):
    """A run that fails on a user error (a mesh missing) removes the cache folder it created,
    with its missing parents; a cache folder that existed stays."""
    root = make_tiny_scene(tmp_path / "broken")
    (root / "meshes/block.ply").unlink()
    cache = tmp_path / "new" / "cache"
    proc = cli([f"scene.dir={root}", *TINY, f"hydra.run.dir={tmp_path / 'run'}", f"cache.dir={cache}"], tmp_path)
    assert error_line(proc).endswith("mesh file missing; fix the path in scene.yaml")
    assert not (tmp_path / "new").exists() and not (tmp_path / "run").exists()
    (tmp_path / "mine").mkdir()
    proc = cli([f"scene.dir={root}", *TINY, f"hydra.run.dir={tmp_path / 'run'}", f"cache.dir={tmp_path / 'mine'}"],
                tmp_path)
    assert proc.returncode == 2 and (tmp_path / "mine").is_dir()


# ----------------------------------------------------------------------------------------------
# 13. File modes
# ----------------------------------------------------------------------------------------------

def test_results_json_non_finite_written_as_null(tmp_path, caplog):
    """A non-finite number reaches results.json as null with a warning naming its place (was: the
    finished run failed at the write, ValueError "Out of range float values are not JSON compliant")."""
    from framework.results import write_results
    path = write_results(tmp_path, {"a": [1.0, float("nan")], "b": {"c": np.float32("inf")}, "d": 0.5})
    assert json.loads(path.read_text()) == {"a": [1.0, None], "b": {"c": None}, "d": 0.5}
    assert "non-finite numbers written as null at a[1], b.c" in caplog.text


def test_results_json_follows_the_umask(tmp_path):
    """results.json gets 0666 less the umask, as the images do (was: 0600, mkstemp's)."""
    from framework.results import write_results
    old = os.umask(0o022)
    try:
        path = write_results(tmp_path, {"a": 1})
        (tmp_path / "plain").write_text("")
    finally:
        os.umask(old)
    assert oct(path.stat().st_mode & 0o777) == oct((tmp_path / "plain").stat().st_mode & 0o777) == "0o644"
