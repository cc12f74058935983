"""``framework.convert``: each reader, polygons with holes and non-convex ones, the move to a
local origin in float64, kernels by semantic type and by ``--kernels``, provenance, and the
``origin`` key of scene.yaml.

Areas are sums of triangle areas in float64 of coordinates written with 1 mm resolution near
the origin: compared to 1e-6 relative. Camera centres after the move are compared to 1e-6 m:
float64 at 6.9e6 m resolves 1e-9 m, float32 would be off by up to 0.5 m.
"""
from __future__ import annotations

import hashlib

import numpy as np
import pytest
import yaml

from convert_inputs import (GROUND, ORIGIN, WALL, camera_local, corner_cityjson, corner_glb, corner_obj, labelled_ply,
                            obj_text, write_delivery)
from framework.convert import convert
from framework.errors import SceneError
from framework.scene import load_scene


def _convert(tmp_path, source, **kw):
    d = write_delivery(tmp_path / "delivery")
    return convert(source, tmp_path / "out", sparse=d["sparse"], emitters=d["emitters"], **kw)


def _areas(folder) -> dict[str, float]:
    scene = load_scene(folder, observations=False)
    out: dict[str, float] = {}
    for m in scene.meshes:
        out[scene.segments[m.segment].name] = out.get(scene.segments[m.segment].name, 0.0) + m.area
    return out


def test_obj_materials_origin_and_cameras(tmp_path):
    done = _convert(tmp_path, corner_obj(tmp_path))
    np.testing.assert_array_equal(done.origin, ORIGIN)
    scene = load_scene(done.folder, observations=False)
    assert scene.origin == tuple(ORIGIN)
    assert {s.name: s.kernels for s in scene.segments} == {"ground": ("diffuse",), "wall": ("diffuse",)}
    assert _areas(done.folder) == pytest.approx({"ground": 400.0, "wall": 160.0}, rel=1e-6)
    lo = np.min([m.vertices.min(0) for m in scene.meshes], 0)
    np.testing.assert_allclose(lo, [-10, -10, 0], atol=1e-9)
    T, want = scene.cameras[0].cam_from_world, camera_local().cam_from_world
    np.testing.assert_allclose(-T[:, :3].T @ T[:, 3], -want[:, :3].T @ want[:, 3], atol=1e-6)


def test_obj_objects(tmp_path):
    source = tmp_path / "corner.obj"
    source.write_text(obj_text({"kerb": [GROUND], "house": [WALL]}, key="o"))
    done = _convert(tmp_path, source, group="object")
    assert list(done.segments) == ["kerb", "house"]


def test_non_convex_polygon_is_not_a_fan(tmp_path):
    """A wall with a door notch (an 8-gon, non-convex): earcut keeps its area; a fan from vertex 0
    would cover the notch and add its 2 m x 2 m."""
    notch = [[-10, 10, 0], [-1, 10, 0], [-1, 10, 2], [1, 10, 2], [1, 10, 0], [10, 10, 0], [10, 10, 8], [-10, 10, 8]]
    source = tmp_path / "notch.obj"
    source.write_text(obj_text({"ground": [GROUND], "wall": [notch]}))
    assert _areas(_convert(tmp_path, source).folder)["wall"] == pytest.approx(160.0 - 4.0, rel=1e-6)


def test_cityjson_semantics_holes_and_window_kernels(tmp_path):
    done = _convert(tmp_path, corner_cityjson(tmp_path))
    assert done.segments == {"ground/unclassified": ("diffuse",), "house/WallSurface": ("diffuse",),
                             "house/Window": ("diffuse", "specular")}
    areas = _areas(done.folder)
    assert areas["house/WallSurface"] == pytest.approx(160.0 - 4.0, rel=1e-6)    # the window's hole
    assert areas["house/Window"] == pytest.approx(4.0, rel=1e-6)
    np.testing.assert_array_equal(done.origin, ORIGIN)
    scene = load_scene(done.folder, observations=False)
    wall = next(m for m in scene.meshes if scene.segments[m.segment].name == "house/WallSurface")
    normals = np.cross(*(wall.vertices[wall.faces[:, i]] - wall.vertices[wall.faces[:, 0]] for i in (1, 2)))
    assert (normals[:, 1] < 0).all()                     # every triangle wound as the ring: towards -y


def test_cityjson_object_grouping_and_kernel_overrides(tmp_path):
    done = _convert(tmp_path, corner_cityjson(tmp_path), group="object",
                    kernels={"house": ("diffuse", "glossy(0.2)")}, default_kernels=("diffuse", "specular"))
    assert done.segments == {"ground": ("diffuse", "specular"), "house": ("diffuse", "glossy(0.2)")}


def test_cityjson_window_default_overridden_by_pattern(tmp_path):
    done = _convert(tmp_path, corner_cityjson(tmp_path), kernels={"*/Window": ("diffuse",)})
    assert done.segments["house/Window"] == ("diffuse",)


def test_gltf_materials_y_up(tmp_path):
    """A GLB (+y up, as exporters write it) of the corner: segments by material, back to +z up."""
    source = corner_glb(tmp_path)
    done = _convert(tmp_path, source)
    assert _areas(done.folder) == pytest.approx({"ground": 400.0, "wall": 160.0}, rel=1e-6)
    # glTF stores float32: the survey offset survives to its resolution (0.5 m at 6.9e6 m), so
    # the origin is compared to 1 m
    np.testing.assert_allclose(done.origin, ORIGIN, atol=1.0)


def test_labelled_ply(tmp_path):
    done = _convert(tmp_path, labelled_ply(tmp_path, {0: "ground", 1: "wall"}))
    assert _areas(done.folder) == pytest.approx({"ground": 400.0, "wall": 160.0}, rel=1e-6)
    np.testing.assert_array_equal(done.origin, ORIGIN)


def test_provenance(tmp_path):
    source = corner_cityjson(tmp_path)
    done = _convert(tmp_path, source)
    digest = hashlib.sha256(source.read_bytes()).hexdigest()
    readme = (done.folder / "README.md").read_text()
    assert f"`{digest}`" in readme and "`corner.city.json` (CityJSON, version 2.0)" in readme
    assert f"sha256 {digest}" in (done.folder / "scene.yaml").read_text()


def test_local_geometry_keeps_its_frame(tmp_path):
    """Coordinates within 1 km of 0 are not moved: origin [0, 0, 0]."""
    source = tmp_path / "local.obj"
    source.write_text(obj_text({"ground": [GROUND], "wall": [WALL]}, origin=np.zeros(3)))
    d = write_delivery(tmp_path / "delivery", shift=-ORIGIN)
    done = convert(source, tmp_path / "out", sparse=d["sparse"], emitters=d["emitters"])
    np.testing.assert_array_equal(done.origin, [0.0, 0.0, 0.0])
    assert _areas(done.folder) == pytest.approx({"ground": 400.0, "wall": 160.0}, rel=1e-6)


def test_scene_yaml_origin_checked(tmp_path):
    done = _convert(tmp_path, corner_obj(tmp_path))
    path = done.folder / "scene.yaml"
    desc = yaml.safe_load(path.read_text())
    desc["origin"] = [1.0, 2.0]
    path.write_text(yaml.safe_dump(desc))
    with pytest.raises(SceneError, match=r"origin must be 3 finite numbers \[x, y, z\]"):
        load_scene(done.folder, observations=False)


@pytest.mark.parametrize("origin, shown", [([652340.0, 6862275.0, 35.0], "652340.000, 6862275.000, 35.000"),
                                           (None, "none (the scene's own frame)")])
def test_run_report_names_the_origin(origin, shown):
    """results.json's ``origin`` is in the run report's overview."""
    from reports.doc import Doc
    from reports.run import _section_overview

    doc = Doc("run")
    _section_overview(doc, {"scene": "street", "method": "symbolic", "channels": ["R", "G", "B"], "renders": 1,
                            "image_rmse": 0.01, "origin": origin, "settings": {}})
    assert f"| Origin (survey coordinates of the scene's 0, 0, 0) | {shown} |" in doc.render_md()


def test_cityjson_1_1_multisolid_and_materials(tmp_path):
    """A CityJSON 1.1 building as a MultiSolid (one box) with an appearance material per surface:
    ``--group material`` names segments by material, ``semantic`` by surface type."""
    import json

    corners = [[-10, -10, 0], [10, -10, 0], [10, 10, 0], [-10, 10, 0]]
    verts = [[int(x) * 1000 for x in np.add(c, [0, 0, z])] for z in (0, 8) for c in corners]
    box = [[[0, 3, 2, 1]], [[4, 5, 6, 7]], [[0, 1, 5, 4]], [[1, 2, 6, 5]], [[2, 3, 7, 6]], [[3, 0, 4, 7]]]
    geom = {"type": "MultiSolid", "lod": "2", "boundaries": [[box]],
            "semantics": {"surfaces": [{"type": "GroundSurface"}, {"type": "RoofSurface"}, {"type": "WallSurface"}],
                          "values": [[[0, 1, 2, 2, 2, 2]]]},
            "material": {"colour": {"values": [[[1, 0, 1, 1, 1, 1]]]}}}
    doc = {"type": "CityJSON", "version": "1.1", "transform": {"scale": [0.001] * 3, "translate": ORIGIN.tolist()},
           "appearance": {"materials": [{"name": "tiles"}, {"name": "render"}]},
           "CityObjects": {"house": {"type": "Building", "geometry": [geom]}}, "vertices": verts}
    source = tmp_path / "house.city.json"
    source.write_text(json.dumps(doc))
    d = write_delivery(tmp_path / "delivery")
    semantic = convert(source, tmp_path / "a", sparse=d["sparse"], emitters=d["emitters"], check_views=False)
    assert list(semantic.segments) == ["house/GroundSurface", "house/RoofSurface", "house/WallSurface"]
    material = convert(source, tmp_path / "b", sparse=d["sparse"], emitters=d["emitters"], group="material",
                       check_views=False)
    assert list(material.segments) == ["render", "tiles"]
    assert _areas(material.folder) == pytest.approx({"tiles": 400.0, "render": 400.0 + 4 * 160.0}, rel=1e-6)


def test_gltf_nodes(tmp_path):
    """``--group object`` on a GLB: one segment per node, named after it."""
    import trimesh

    scene = trimesh.Scene()
    for name, quad in (("kerb", GROUND), ("house", WALL)):
        v = (np.array(quad, float) + ORIGIN) @ np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]]).T
        scene.add_geometry(trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False), node_name=name,
                           geom_name=f"{name}_mesh")
    source = tmp_path / "corner.glb"
    source.write_bytes(scene.export(file_type="glb"))
    done = _convert(tmp_path, source, group="object")
    assert sorted(done.segments) == ["house", "kerb"]
