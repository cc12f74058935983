"""The field-photograph scene builder (``scenes/urban_canyon_field.py``) at a tiny size.

Two builds of 32 x 32 photographs at 8 spp: the files of the scene format's field photographs
(distorted COLMAP cameras, JPEGs, masks, photometry), the truth file, determinism, and the
pieces (gains, render camera coverage, encoding, mask dilation) on their own.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from scenes import urban_canyon
from scenes import urban_canyon_field as field

SIZE, SPP = 32, 8
NAMES = [f"street_{i:03d}.jpg" for i in range(8)] + ["aerial_000.jpg"]


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("field")
    return (field.build(root / "urban_canyon_field", image=SIZE, spp=SPP),
            field.build(root / "again" / "urban_canyon_field", image=SIZE, spp=SPP))


def _truth(folder: Path) -> dict:
    return yaml.safe_load((folder / "truth.yaml").read_text())


@pytest.mark.slow
def test_cameras_are_distorted_models(built):
    import pycolmap

    folder = built[0]
    rec = pycolmap.Reconstruction(str(folder / "sparse"))
    by_name = {im.name: rec.cameras[im.camera_id] for im in rec.images.values()}
    assert sorted(by_name) == sorted(NAMES)
    for i, name in enumerate(NAMES):
        cam = by_name[name]
        assert (cam.width, cam.height) == (SIZE, SIZE)
        assert abs(cam.principal_point_x - SIZE / 2) < 0.5 and abs(cam.principal_point_y - SIZE / 2) < 0.5
        if i % 2 == 0:
            assert cam.model.name == "SIMPLE_RADIAL" and -0.09 < cam.params[3] < -0.07
        else:
            assert cam.model.name == "OPENCV"
            assert cam.focal_length_x / cam.focal_length_y == pytest.approx(1.0201, abs=1e-3)
            k1, k2, p1, p2 = cam.params[4:]
            assert -0.11 < k1 < -0.09 and 0.017 < k2 < 0.023 and 4e-4 < abs(p1) < 2e-3 and 4e-4 < abs(p2) < 2e-3
    text = (folder / "sparse" / "cameras.txt").read_text()
    assert text.count(" SIMPLE_RADIAL ") == 5 and text.count(" OPENCV ") == 4


def test_images_and_masks(built):
    from PIL import Image

    folder = built[0]
    assert sorted(p.name for p in (folder / "images").iterdir()) == sorted(NAMES)
    assert sorted(p.name for p in (folder / "masks").iterdir()) == sorted(f"{n}.png" for n in NAMES)
    zeros = {}
    for name in NAMES:
        with Image.open(folder / "images" / name) as im:
            assert im.format == "JPEG" and im.mode == "RGB" and im.size == (SIZE, SIZE)
            assert np.asarray(im).std() > 0
        with Image.open(folder / "masks" / f"{name}.png") as m:
            assert m.format == "PNG" and m.mode == "L" and m.size == (SIZE, SIZE)
            mask = np.asarray(m)
        assert set(np.unique(mask)) <= {0, 255}
        zeros[name] = int((mask == 0).sum())
    truth = _truth(folder)["objects"]
    assert zeros == truth["car"]["masked_pixels"]
    street_with_car = [n for n in NAMES if n.startswith("street") and zeros[n] > 0]
    assert len(street_with_car) >= 3, zeros
    assert sum(v > 0 for k, v in truth["pedestrian"]["pixels"].items() if k.startswith("street")) >= 2
    assert truth["car"]["masked"] is True and truth["pedestrian"]["masked"] is False


def test_scene_yaml_is_the_model_plus_photometry(built):
    folder = built[0]
    scene = yaml.safe_load((folder / "scene.yaml").read_text())
    assert scene["photometry"] == {"encoding": "srgb", "exposure": "per_view",
                                   "reference_view": "street_002.jpg", "saturation": 0.99}
    assert [s["name"] for s in scene["segments"]] == list(urban_canyon.REFERENCES)
    assert not any("car" in m or "pedestrian" in m for s in scene["segments"] for m in s["meshes"])
    assert [e["type"] for e in scene["emitters"]] == ["envmap", "directional"]
    assert {str(p.relative_to(folder)) for p in folder.glob("meshes/*.ply")} == \
        {m for s in scene["segments"] for m in s["meshes"]}


def test_truth_gains(built):
    truth = _truth(built[0])
    gains = truth["gains"]
    assert list(gains) == NAMES and truth["reference_view"] == "street_002.jpg"
    assert gains["street_002.jpg"] == [1.0, 1.0, 1.0]
    for name, g in gains.items():
        g = np.asarray(g)
        assert g.shape == (3,) and g.max() / g.min() <= 1.11
        assert 0.5 <= g.min() and g.max() <= 2.0
        if name in field.OVEREXPOSED:
            assert g.min() > 1.6
    assert set(truth["clipped_pixels"]) == set(NAMES) == set(truth["saturated_pixels"])
    assert truth["cameras"]["street_001.jpg"]["model"] == "OPENCV"


def test_build_is_deterministic(built):
    a, b = built
    files = sorted(str(p.relative_to(a)) for p in a.rglob("*") if p.is_file())
    assert files == sorted(str(p.relative_to(b)) for p in b.rglob("*") if p.is_file())
    differ = [f for f in files if (a / f).read_bytes() != (b / f).read_bytes()]
    assert differ == []


def test_folder_loads(built):
    from framework.scene import load_scene

    scene = load_scene(built[0])
    assert sorted(c.name for c in scene.cameras) == sorted(NAMES)
    assert [s.name for s in scene.segments] == list(urban_canyon.REFERENCES)


def test_gains_and_models_do_not_depend_on_size():
    assert field.gains(NAMES) == field.gains(NAMES)
    assert field.gains(NAMES)["street_002.jpg"] == [1.0, 1.0, 1.0]
    small, large = field.camera_models(field.views(32)), field.camera_models(field.views(200))
    for (m1, p1), (m2, p2) in zip(small, large):
        assert m1 == m2
        assert p1[-1] == p2[-1]                      # distortion coefficients do not scale


def test_render_camera_covers_the_distorted_view():
    from framework.scene.undistort import resample

    for view, (model, params) in zip(field.views(), field.camera_models(field.views())):
        r = field.render_camera(view, model, params)
        assert r.f == pytest.approx(2 * max(params[:2] if model == "OPENCV" else params[:1]))
        assert (r.cx, r.cy) == (r.width / 2, r.height / 2) and r.width < 2.4 * view.width
        source = field._colmap_camera(r.width, r.height, "PINHOLE", [r.f, r.f, r.cx, r.cy])
        target = field._colmap_camera(view.width, view.height, model, params)
        _, ok = resample(np.ones((r.height, r.width)), source=source, target=target)
        assert ok.all()


def test_encode_clips_and_quantises():
    x = np.array([[[0.0, 0.5, 1.2], [0.2, 0.2, 0.2]], [[2.0, 2.0, 2.0], [-0.1, 0.0, 0.999]]])
    codes, clipped = field.encode(x)
    assert codes.dtype == np.uint8 and clipped == 2
    assert codes[0, 0, 2] == 255 and codes[1, 1, 0] == 0 and codes[0, 0, 1] == 188


def test_dilate_by_two_pixels():
    m = np.zeros((9, 9), bool)
    m[4, 4] = True
    d = field.dilate(m)
    assert d.sum() == 25 and d[2:7, 2:7].all()
