"""``cornell_box``: Mitsuba's built-in ``mi.cornell_box()`` converted to the scene format.

Each shape of the dict is loaded, its triangles (after ``to_world``) are written to one PLY;
the ``rectangle`` shapes, which are not meshes in Mitsuba, are written as two triangles with the
rectangle's winding (normal = ``to_world`` applied to local +z). Segments ``white``, ``red``,
``green`` (kernel ``diffuse``) take the dict's exact RGB albedos; the light is an ``area``
emitter with the dict's radiance, and its mesh also belongs to ``white`` (the dict gives it the
white BSDF). The dict's sensor (256x256, fov 39.3077 with ``fov_axis: smaller``, i.e. along x
for a square image) becomes a 64x64 COLMAP view of the same field of view, to keep tests fast.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from framework.render.backend import set_variant
from framework.scene.write import pinhole_camera, write_colmap, write_mesh, write_scene_yaml
from scenes import geometry as g
from scenes.cameras import cam_from_mitsuba, focal_from_fov

IMAGE = 64


def _matrix(transform) -> np.ndarray:
    return np.array(transform.matrix, dtype=float).reshape(4, 4)


def shape_mesh(shape: dict) -> g.Mesh:
    """World-space triangles of one shape dict of the Cornell box."""
    import mitsuba as mi

    if shape["type"] == "rectangle":
        m = _matrix(shape["to_world"])
        local = np.array([[-1, -1, 0, 1], [1, -1, 0, 1], [1, 1, 0, 1], [-1, 1, 0, 1]], float)
        return (local @ m.T)[:, :3], np.array([[0, 1, 2], [0, 2, 3]])
    params = mi.traverse(mi.load_dict({"type": shape["type"], "to_world": shape["to_world"]}))
    return (np.array(params["vertex_positions"], float).reshape(-1, 3),
            np.array(params["faces"], int).reshape(-1, 3))


def _bsdf_id(shape: dict) -> str:
    return shape["bsdf"]["id"]


def build(folder: Path) -> Path:
    """Write the scene folder from ``mi.cornell_box()``."""
    set_variant("auto", channels=("R", "G", "B"))
    import mitsuba as mi

    folder, box = Path(folder), mi.cornell_box()
    shapes = {k: v for k, v in box.items() if isinstance(v, dict) and v.get("type") in ("rectangle", "cube")}
    files: dict[str, list[str]] = {}
    emitters = []
    for name, shape in shapes.items():
        rel = f"meshes/{name}.ply"
        write_mesh(folder / rel, *shape_mesh(shape))
        files.setdefault(_bsdf_id(shape), []).append(rel)
        if "emitter" in shape:
            emitters.append({"type": "area", "meshes": [rel],
                             "radiance": list(shape["emitter"]["radiance"]["value"])})
    segments = [{"name": b, "meshes": files[b], "kernels": ["diffuse"],
                 "reference": {"diffuse": list(box[b]["reflectance"]["value"])}} for b in files]
    sensor = box["sensor"]
    focal = focal_from_fov(IMAGE, sensor["fov"])     # square image: fov_axis 'smaller' is x
    view = pinhole_camera("cornell_000.png", IMAGE, IMAGE, focal, cam_from_mitsuba(_matrix(sensor["to_world"])))
    write_colmap(folder / "sparse", [view])
    write_scene_yaml(folder / "scene.yaml", {"name": folder.name, "channels": "rgb",
                                             "segments": segments, "emitters": emitters}, __doc__.split("\n\n", 1)[1])
    return folder
