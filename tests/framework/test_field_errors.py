"""Bad field input: one SceneError per case, one line naming the file (and camera, image or key)
and the fix; two cases through the command line (exit 2, that one line, no run folder)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from factory import edit_scene_yaml, make_tiny_scene, scene_error_message, write_png8

import framework.run
from framework.scene import load_scene


_message = scene_error_message


def _camera_line(root: Path, camera: int, line: str) -> None:
    """Replace camera ``camera``'s line of ``sparse/cameras.txt`` by ``<camera> <line>``."""
    path = root / "sparse/cameras.txt"
    lines = [f"{camera} {line}" if ln.split()[:1] == [str(camera)] else ln for ln in path.read_text().splitlines()]
    path.write_text("\n".join(lines) + "\n")


def _photos(root: Path, n: int = 2, value: int = 120, **write) -> None:
    for i in range(n):
        write_png8(root / "images" / f"view_{i}.png", np.full((16, 16, 3), value), **write)


# ----------------------------------------------------------------------------------------------
# Cameras
# ----------------------------------------------------------------------------------------------

def test_fisheye_camera(tiny_scene):
    _camera_line(tiny_scene, 2, "OPENCV_FISHEYE 16 16 13.8 13.8 8 8 0.1 0.01 0 0")
    msg = _message(tiny_scene, r"cameras.txt: camera 2 \(of image view_1.png\) is OPENCV_FISHEYE, a fisheye "
                               r"model; undistort the images to a pinhole camera \(colmap image_undistorter\) "
                               r"or use SIMPLE_RADIAL, RADIAL or OPENCV$")
    assert msg.startswith(str(tiny_scene / "sparse/cameras.txt"))


@pytest.mark.parametrize("line, match", [
    ("FULL_OPENCV 16 16 13.8 13.8 8 8 0 0 0 0 0 0 0 0",
     r"camera 2 \(of image view_1.png\) is FULL_OPENCV, a model the loader does not resample; undistort"),
    ("FOV 16 16 13.8 13.8 8 8 0.1", r"camera 2 \(of image view_1.png\) is FOV, a fisheye model"),
    ("OPENCV 16 16 13.8 13.8 8 8 0.1 0.01", r"line 5: an OPENCV camera has 8 parameters \(fx fy cx cy k1 k2 "
                                            r"p1 p2\), this line 6; fix the line"),
    ("SIMPLE_RADIAL 16 16 13.8 8 8", r"line 5: a SIMPLE_RADIAL camera has 4 parameters \(f cx cy k\), this line 3"),
    ("OPENCV_FISHEYE 16 16 13.8", r"line 5: an OPENCV_FISHEYE camera has 8 parameters"),
    ("PINHOLE_FISH 16 16 1 2 3 4", r"line 5: camera model 'PINHOLE_FISH' is not a COLMAP model; use "
                                   r"SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV$"),
])
def test_other_camera_problems(tiny_scene, line, match):
    _camera_line(tiny_scene, 2, line)
    _message(tiny_scene, match)


# ----------------------------------------------------------------------------------------------
# Images and masks
# ----------------------------------------------------------------------------------------------

def test_undecodable_image(tiny_scene):
    _photos(tiny_scene)
    (tiny_scene / "images/view_1.png").write_bytes(b"not an image")
    msg = _message(tiny_scene, r"view_1.png: image cannot be decoded \(cannot identify image file\); "
                               r"re-export it as PNG or JPEG$")
    assert msg.startswith(str(tiny_scene / "images/view_1.png"))


@pytest.mark.parametrize("bits", [8, 16])
def test_truncated_image(tiny_scene, bits):
    """A PNG cut short: Pillow (8 bit) and Mitsuba's libpng (16-bit colour) both name it."""
    from factory import write_png16
    _photos(tiny_scene)
    path = tiny_scene / "images/view_0.png"
    codes = np.random.default_rng(0).integers(1, 250, (16, 16, 3))
    if bits == 16:
        write_png16(path, codes * 256)
    else:
        write_png8(path, codes)
    path.write_bytes(path.read_bytes()[:70])
    _message(tiny_scene, r"images/view_0.png: image cannot be decoded \(.+\); re-export it as PNG or JPEG$")


def test_unsupported_and_missing_images(tiny_scene):
    _photos(tiny_scene, n=1)
    _message(tiny_scene, r"images/view_1.exr: missing EXR file; add it or the image as delivered "
                         r"\(images/view_1.png: .exr, .png or .jpg\), or fix its name in the scene$")
    write_png8(tiny_scene / "images/view_1.gif", np.full((16, 16, 3), 9), fmt="GIF")
    (tiny_scene / "images/view_1.gif").rename(tiny_scene / "images/view_1.png")
    _message(tiny_scene, r"view_1.png: image cannot be decoded \(a GIF file, not PNG or JPEG\)")
    (tiny_scene / "images/view_1.png").rename(tiny_scene / "images/view_1.tif")
    (tiny_scene / "sparse/images.txt").write_text(
        (tiny_scene / "sparse/images.txt").read_text().replace("view_1.png", "view_1.tif"))
    _message(tiny_scene, r"images/view_1.tif: .tif images are not read; deliver the image as .exr, .png or "
                         r".jpg, or add images/view_1.exr$")


def test_image_channels_and_size(tmp_path, tiny_scene):
    _photos(tiny_scene, n=2)
    write_png8(tiny_scene / "images/view_0.png", np.full((16, 16), 120))
    _message(tiny_scene, r"view_0.png: a grey image \(1 channel\); this scene needs R,G,B: deliver colour images")
    write_png8(tiny_scene / "images/view_0.png", np.full((12, 16, 3), 120))
    _message(tiny_scene, r"view_0.png: image is 16x12, its camera is 16x16; give it that size$")
    mono = make_tiny_scene(tmp_path / "mono", channels="mono")
    _photos(mono)
    _message(mono, r"view_0.png: a colour image \(3 channels\); this scene is mono \(one channel Y\): deliver "
                   "grey images$")


def test_mask_of_the_wrong_size(tiny_scene):
    _photos(tiny_scene)
    write_png8(tiny_scene / "masks/view_1.png.png", np.full((16, 8), 255))
    msg = _message(tiny_scene, r"masks/view_1.png.png: mask is 8x16, its image view_1.png is 16x16; make the "
                               r"mask the image's size$")
    assert msg.startswith(str(tiny_scene / "masks/view_1.png.png"))


def test_undecodable_mask(tiny_scene):
    _photos(tiny_scene)
    (tiny_scene / "masks").mkdir()
    (tiny_scene / "masks/view_0.png.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    _message(tiny_scene, r"masks/view_0.png.png: mask cannot be decoded \(.+\); re-export it as a grey PNG$")


# ----------------------------------------------------------------------------------------------
# scene.yaml photometry
# ----------------------------------------------------------------------------------------------

def test_reference_view_not_in_the_model(tiny_scene):
    edit_scene_yaml(tiny_scene, lambda d: d.update(photometry={"exposure": "per_view",
                                                               "reference_view": "view_7.png"}))
    msg = _message(tiny_scene, r"scene.yaml: photometry reference_view 'view_7.png' is not an image of "
                               r".*sparse/images.txt; name one of: view_0.png, view_1.png$")
    assert msg.startswith(str(tiny_scene / "scene.yaml"))


def test_per_view_exposure_without_reference_view(tiny_scene):
    edit_scene_yaml(tiny_scene, lambda d: d.update(photometry={"exposure": "per_view"}))
    _message(tiny_scene, r"scene.yaml: photometry exposure per_view needs reference_view: add reference_view: "
                         r"<an image name of images.txt>, the view whose gains are 1")


def test_unknown_encoding(tiny_scene):
    edit_scene_yaml(tiny_scene, lambda d: d.update(photometry={"encoding": "gamma22"}))
    _message(tiny_scene, r"scene.yaml: photometry encoding 'gamma22' unknown; use linear \(pixel values are "
                         r"radiance\) or srgb \(8/16-bit camera output, decoded to linear\)$")


@pytest.mark.parametrize("photometry, match", [
    ({"encodng": "srgb"}, r"photometry: unknown key 'encodng' \(did you mean 'encoding'\?\); allowed keys: "
                          r"encoding, exposure, reference_view, saturation, vignetting, resampling$"),
    ({"resampling": "lanczos"}, r"photometry resampling 'lanczos' unknown; use bilinear \(2 x 2 pixels\) or cubic"),
    ({"exposure": "auto"}, r"photometry exposure 'auto' unknown; use known \(pixel = radiance\) or per_view"),
    ({"reference_view": "view_0.png"}, r"photometry reference_view is used only with exposure: per_view"),
    ({"saturation": 1.5}, r"photometry saturation = 1.5 must lie in \(0, 1\]"),
    ({"saturation": 0}, r"photometry saturation = 0 must lie in \(0, 1\]"),
    ({"saturation": "high"}, r"photometry saturation must be a number in \(0, 1\]; got the string 'high'"),
    ({"exposure": "per_view", "reference_view": 3}, r"photometry reference_view must be a non-empty string"),
    ("srgb", r"photometry must be a mapping with keys encoding, exposure, reference_view, saturation"),
])
def test_other_photometry_problems(tiny_scene, photometry, match):
    edit_scene_yaml(tiny_scene, lambda d: d.update(photometry=photometry))
    _message(tiny_scene, match)


def test_photometry_is_read(tiny_scene):
    edit_scene_yaml(tiny_scene, lambda d: d.update(photometry={"encoding": "srgb", "exposure": "per_view",
                                                               "reference_view": "view_1.png", "saturation": 0.95,
                                                               "resampling": "cubic"}))
    p = load_scene(tiny_scene).photometry
    assert (p.encoding, p.exposure, p.reference_view, p.saturation) == ("srgb", "per_view", "view_1.png", 0.95)
    assert p.resampling == "cubic"


# ----------------------------------------------------------------------------------------------
# The command line
# ----------------------------------------------------------------------------------------------

def _cli_error(scene: Path, tmp_path: Path) -> str:
    """``python -m framework.run`` on ``scene``: exit status 2, one line on stderr (returned),
    no run folder."""
    env = dict(os.environ, HYDRA_FULL_ERROR="0", PYTHONPATH=str(Path(framework.run.__file__).parents[1]))
    run = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "framework.run", f"scene.dir={scene}", f"hydra.run.dir={run}",
                           f"cache.dir={tmp_path / 'cache'}", "render.spp=4", "observe.spp=8", "report=false"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr[-2000:]
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, proc.stderr[-2000:]
    assert not run.exists()
    return lines[0]


@pytest.mark.slow
def test_cli_fisheye_camera(tiny_scene, tmp_path):
    _camera_line(tiny_scene, 1, "OPENCV_FISHEYE 16 16 13.8 13.8 8 8 0.1 0.01 0 0")
    assert _cli_error(tiny_scene, tmp_path) == (
        f"error: {tiny_scene / 'sparse/cameras.txt'}: camera 1 (of image view_0.png) is OPENCV_FISHEYE, a fisheye "
        "model; undistort the images to a pinhole camera (colmap image_undistorter) or use SIMPLE_RADIAL, RADIAL "
        "or OPENCV")


@pytest.mark.slow
def test_cli_undecodable_image(tiny_scene, tmp_path):
    _photos(tiny_scene)
    (tiny_scene / "images/view_0.png").write_bytes(b"GIF89a broken")
    assert _cli_error(tiny_scene, tmp_path) == (
        f"error: {tiny_scene / 'images/view_0.png'}: image cannot be decoded (cannot identify image file); "
        "re-export it as PNG or JPEG")


@pytest.mark.slow
def test_cli_unknown_encoding(tiny_scene, tmp_path):
    edit_scene_yaml(tiny_scene, lambda d: d.update(photometry={"encoding": "log"}))
    assert _cli_error(tiny_scene, tmp_path).startswith(
        f"error: {tiny_scene / 'scene.yaml'}: photometry encoding 'log' unknown; use linear")
