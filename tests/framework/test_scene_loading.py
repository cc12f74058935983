"""Loaders against hand-computed values and independent tools (pycolmap, Open3D, Mitsuba)."""
from __future__ import annotations

import numpy as np
import pytest

from framework.images import write_exr
from framework.scene import load_scene


def test_mesh_areas_and_normals(tiny_scene):
    """Ground quad 10 m x 10 m = 100 m²; box 2x2x2 m = 24 m² (by hand); quad normal +z."""
    scene = load_scene(tiny_scene)
    areas = {m.path: m.area for m in scene.meshes}
    assert areas["meshes/ground.ply"] == pytest.approx(100.0, rel=1e-12)
    assert areas["meshes/block.ply"] == pytest.approx(24.0, rel=1e-12)
    g = next(m for m in scene.meshes if m.path == "meshes/ground.ply")
    a, b, c = g.vertices[g.faces[0]]
    n = np.cross(b - a, c - a)
    np.testing.assert_allclose(n / np.linalg.norm(n), [0, 0, 1], atol=1e-12)


def test_segments_parameters_references(tiny_scene):
    scene = load_scene(tiny_scene)
    params = scene.parameters()
    assert [(p.segment_name, p.kernel) for p in params] == [
        ("ground", "diffuse"), ("ground", "specular"), ("block", "diffuse"), ("block", "specular")]
    np.testing.assert_allclose(scene.reference(params)[0], [0.5, 0.4, 0.3])
    diffuse_only = scene.parameters(kernels=("diffuse",))
    np.testing.assert_allclose(scene.reference(diffuse_only)[1], [0.3, 0.6, 0.5])


def test_colmap_point_lies_on_mitsuba_ray(tiny_scene):
    """A world point projected by pycolmap's camera model lies on the Mitsuba sensor ray
    through that pixel position (distance < 1e-4 m at ~8 m, i.e. far below a pixel)."""
    import mitsuba as mi
    import pycolmap

    from framework.render.mitsuba_scene import MitsubaScene
    scene = load_scene(tiny_scene)
    rec = pycolmap.Reconstruction(str(tiny_scene / "sparse"))
    ms = MitsubaScene(scene, list(scene.cameras), spp=1)
    pts = np.array([[0.3, -0.2, 1.7], [1.0, 1.0, 0.0], [-0.7, 0.4, 0.9]])
    for i, cam in enumerate(scene.cameras):
        image = rec.find_image_with_name(cam.name)
        T = image.cam_from_world().matrix()
        pc = pts @ T[:, :3].T + T[:, 3]
        px = rec.cameras[image.camera_id].img_from_cam(pc)        # independent projection
        np.testing.assert_allclose(px, cam.project(pts), atol=1e-9)
        pos = mi.Point2f((px[:, 0] / cam.width).astype(np.float32), (px[:, 1] / cam.height).astype(np.float32))
        ray, _ = ms.scene.sensors()[i].sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
        o = np.array(ray.o).T
        d = np.array(ray.d).T
        v = pts - o
        dist = np.linalg.norm(v - (v * d).sum(1, keepdims=True) * d, axis=1)
        assert dist.max() < 1e-4, dist


def test_scene_images_folder_loads(tiny_scene):
    scene = load_scene(tiny_scene)
    (tiny_scene / "images").mkdir()
    for c in scene.cameras:
        write_exr(tiny_scene / "images" / c.name.replace(".png", ".exr"),
                  np.full((c.height, c.width, 3), 0.25, np.float32), ("R", "G", "B"))
    scene = load_scene(tiny_scene)
    assert set(scene.images) == {c.name for c in scene.cameras}
    assert scene.images["view_0.png"].shape == (16, 16, 3)


def test_content_hash_changes_with_content(tiny_scene):
    h0 = load_scene(tiny_scene).content_hash
    assert load_scene(tiny_scene).content_hash == h0
    text = (tiny_scene / "scene.yaml").read_text()
    (tiny_scene / "scene.yaml").write_text(text.replace("name: tiny", "name: tiny2"))
    assert load_scene(tiny_scene).content_hash != h0
