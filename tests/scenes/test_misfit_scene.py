"""The misfit scene builder (``scenes/urban_canyon_misfit.py``) at a small size.

Two builds of 40 x 40 photographs at 4 spp: determinism, the model (urban_canyon_field's), the
car's share of the asphalt in its two views (measured at that size by the builder), the pose
offsets, the facade's shift and the tiles' mean.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from scenes import BUNDLED_DIR
from scenes import urban_canyon as uc
from scenes import urban_canyon_field as field
from scenes import urban_canyon_misfit as misfit

SIZE, SPP = 40, 4
NAMES = [f"street_{i:03d}.jpg" for i in range(8)] + ["aerial_000.jpg"]


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("misfit")
    return (misfit.build(root / "urban_canyon_misfit", image=SIZE, spp=SPP),
            misfit.build(root / "again" / "urban_canyon_misfit", image=SIZE, spp=SPP))


def _truth(folder: Path) -> dict:
    return yaml.safe_load((folder / "truth.yaml").read_text())


def test_build_is_deterministic(built):
    a, b = built
    files = sorted(str(p.relative_to(a)) for p in a.rglob("*") if p.is_file())
    assert files == sorted(str(p.relative_to(b)) for p in b.rglob("*") if p.is_file())
    assert [f for f in files if (a / f).read_bytes() != (b / f).read_bytes()] == []


def test_model_is_the_field_scenes(built):
    """scene.yaml is urban_canyon_field's but for the name; no masks; the photographs load."""
    from framework.scene import load_scene

    ours = yaml.safe_load((built[0] / "scene.yaml").read_text())
    theirs = yaml.safe_load((BUNDLED_DIR / "urban_canyon_field" / "scene.yaml").read_text())
    assert ours.pop("name") == "urban_canyon_misfit" and theirs.pop("name") == "urban_canyon_field"
    assert ours == theirs
    assert not (built[0] / "masks").exists()
    scene = load_scene(built[0])
    assert sorted(c.name for c in scene.cameras) == sorted(NAMES) and scene.images is not None


def test_car_covers_the_asphalt_in_two_views(built):
    """The car, unmasked, covers 30-60 % of the model's asphalt pixels in street_001 and
    street_005 and at most 12 % in every other view (at 40 px; the README states the bundled
    size's)."""
    car = _truth(built[0])["car"]
    assert car["masked"] is False and car["views"] == ["street_001.jpg", "street_005.jpg"]
    for name, share in car["asphalt_share"].items():
        if name in car["views"]:
            assert misfit.SHARE_RANGE[0] <= share <= misfit.SHARE_RANGE[1], (name, share)
        else:
            assert share <= 0.12, (name, share)


def test_poses_offset_by_the_stated_pixels(built):
    """COLMAP holds urban_canyon's poses; each true pose is that pose rotated by px / f with px in
    [0.5, 1]; the image motion truth.yaml states is where the rotated camera projects the point
    the COLMAP camera sees at its principal point (at most px: the part of the axis along the
    optical axis turns the image about that point)."""
    from framework.scene import load_scene

    truth = _truth(built[0])["pose"]
    nominal = {c.name: c for c in field.views(SIZE)}
    for cam in load_scene(built[0]).cameras:
        np.testing.assert_allclose(cam.cam_from_world, nominal[cam.name].cam_from_world, atol=1e-5)
    offsets = misfit.pose_offsets(list(nominal.values()))
    for name, cam in nominal.items():
        t = truth[name]
        assert 0.5 <= t["px"] <= 1.0 and t["angle_rad"] * cam.f == pytest.approx(t["px"], rel=1e-4)
        true = misfit.rotated(cam, offsets[name])
        pose = cam.cam_from_world
        ahead = -pose[:, :3].T @ pose[:, 3] + 10.0 * pose[2, :3]          # 10 m along the optical axis
        seen = true.project(ahead[None])[0] - [cam.cx, cam.cy]
        np.testing.assert_allclose(seen, t["image_motion_px"]["centre_shift"], atol=1e-3)
        assert t["image_motion_px"]["centre"] <= t["px"] + 1e-3


def test_rotation_about_an_image_axis_moves_the_centre_by_px():
    cam = field.views(SIZE)[0]
    offset = {"axis": np.array([0.0, 1.0, 0.0]), "px": 0.8, "angle": 0.8 / cam.f}
    assert misfit.image_motion(cam, offset)["centre"] == pytest.approx(0.8, rel=1e-3)


@pytest.fixture(scope="module")
def truth():
    """urban_canyon's meshes, and the segments, meshes, δ and tile statistics of the truth."""
    parts = uc.meshes()
    segments = uc.segments("rgb", {k: [f"meshes/{s}.ply" for s, _ in v] for k, v in parts.items()})
    return parts, *misfit.truth_parts(segments, parts)


def test_tiles_mean_is_the_reference(truth):
    """The walls' tiles: ±20 %, area-weighted mean δ 0 (within 1e-3: exact here), the tiles
    covering the walls' area; each piece inside its 0.5 m cell."""
    parts, _, moved, delta, stats = truth
    assert np.abs(delta).max() == pytest.approx(misfit.TILE_RANGE) and abs(stats["mean_delta"]) < 1e-9
    area = sum(misfit._area(tri) for _, m in parts["wall"] for tri in m[0][m[1]])
    assert stats["area_m2"] == pytest.approx(area, rel=1e-9)
    assert sum(stats["level_area_m2"]) == pytest.approx(area, rel=1e-9)
    tiled_area = sum(misfit._area(tri) for k in range(misfit.LEVELS) for _, m in moved[f"wall_{k}"]
                     for tri in m[0][m[1]])
    assert tiled_area == pytest.approx(area, rel=1e-9)
    v, f = parts["wall"][0][1]
    for cell, poly in misfit.tile_pieces((v, f[:200])):
        lo, hi = np.asarray(cell) * misfit.TILE, (np.asarray(cell) + 1) * misfit.TILE
        assert np.all(poly >= lo - 1e-9) and np.all(poly <= hi + 1e-9)


def test_truth_parts_move_the_north_building_and_texture_the_walls(truth):
    parts, segs, moved, delta, _ = truth
    names = [s["name"] for s in segs]
    assert "wall" not in names and [n for n in names if n.startswith("wall_")] == [f"wall_{k}" for k in range(9)]
    for (stem, m), (_, m0) in zip(moved["window"], parts["window"]):
        shift = m[0] - m0[0]
        expected = [0.0, 0.1, 0.0] if stem.endswith("_north") else [0.0, 0.0, 0.0]
        np.testing.assert_allclose(shift, np.broadcast_to(expected, shift.shape), atol=1e-12)
    ref = np.asarray(uc.REFERENCES["wall"][0])
    wall4 = next(s for s in segs if s["name"] == "wall_4")
    np.testing.assert_allclose(wall4["reference"]["diffuse"], ref * (1 + delta[4]))
    assert wall4["reference"]["specular"] == uc.REFERENCES["wall"][1]


def test_bundled_truth():
    """The bundled folder (200 px) states what the builder promises: the car over 30-60 % of the
    asphalt in street_001 and street_005 (measured 0.507 and 0.426) and at most 10 % elsewhere,
    pose offsets of 0.5-1 px, the tiles' area-weighted mean δ within 1e-3 of 0, no masks."""
    folder = BUNDLED_DIR / "urban_canyon_misfit"
    truth = _truth(folder)
    car = truth["car"]
    assert truth["image_size"] == [200, 200] and not (folder / "masks").exists()
    assert car["views"] == ["street_001.jpg", "street_005.jpg"]
    assert all(v <= 0.10 for k, v in car["asphalt_share"].items() if k not in car["views"])
    assert all(0.5 <= p["px"] <= 1.0 for p in truth["pose"].values())
    assert abs(truth["tiles"]["area_weighted_mean_delta"]) <= 1e-3 and max(map(abs, truth["tiles"]["delta"])) <= 0.2
