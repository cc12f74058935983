"""Small survey deliveries for the converter's tests: a corner (a ground and a wall) in survey
coordinates, one 16 x 16 camera looking at it, and the emitters file."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

from framework.scene.write import pinhole_camera, write_colmap, write_scene_yaml

#: survey coordinates of the corner's local (0, 0, 0), as the converter chooses it (bbox centre in
#: x, y, its bottom in z, rounded to the metre)
ORIGIN = np.array([652340.0, 6862275.0, 35.0])
#: local geometry: the ground z = 0 over x, y in [-10, 10], the wall y = 10 (facing -y), 8 m high
GROUND = [[-10, -10, 0], [10, -10, 0], [10, 10, 0], [-10, 10, 0]]
WALL = [[-10, 10, 0], [10, 10, 0], [10, 10, 8], [-10, 10, 8]]
EMITTERS = [{"type": "constant", "radiance": [0.3, 0.35, 0.45]},
            {"type": "directional", "direction": [0.3, 0.6, -0.75], "irradiance": [3.0, 2.8, 2.5]}]


def camera_local(size: int = 16):
    """A level camera at (0, -6, 1.5) looking along +y at the wall (local frame)."""
    rot = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    centre = np.array([0.0, -6.0, 1.5])
    return pinhole_camera("corner.png", size, size, size / 2 / np.tan(np.radians(30)),
                          np.concatenate([rot, (-rot @ centre)[:, None]], 1))


def write_delivery(root: Path, *, shift=(0.0, 0.0, 0.0)) -> dict[str, Path]:
    """``sparse/`` (the camera in survey coordinates, moved by ``shift`` metres: far away with a
    large shift) and ``emitters.yaml`` under ``root``; returns their paths."""
    from dataclasses import replace

    root.mkdir(parents=True, exist_ok=True)
    cam = camera_local()
    T = cam.cam_from_world
    o = ORIGIN + np.asarray(shift, float)
    cam = replace(cam, cam_from_world=np.concatenate([T[:, :3], (T[:, 3] - T[:, :3] @ o)[:, None]], 1))
    write_colmap(root / "sparse", [cam])
    write_scene_yaml(root / "emitters.yaml", {"channels": "rgb", "emitters": EMITTERS})
    return {"sparse": root / "sparse", "emitters": root / "emitters.yaml"}


def obj_text(parts: dict[str, list[list[list[float]]]], *, key: str = "usemtl", origin=ORIGIN) -> str:
    """An OBJ of ``parts`` (name -> polygons of local points), in survey coordinates (local ones
    with ``origin=(0, 0, 0)``)."""
    lines, faces, n = [], [], 0
    for name, polys in parts.items():
        faces.append(f"{key} {name}")
        for poly in polys:
            lines += ["v " + " ".join(f"{c:.3f}" for c in np.asarray(p) + origin) for p in poly]
            faces.append("f " + " ".join(str(n + k + 1) for k in range(len(poly))))
            n += len(poly)
    return "\n".join(lines + faces) + "\n"


def corner_obj(root: Path, name: str = "corner.obj", **extra) -> Path:
    """The corner as an OBJ with materials ``ground`` and ``wall`` (plus ``extra`` parts)."""
    path = root / name
    path.write_text(obj_text({"ground": [GROUND], "wall": [WALL], **extra}))
    return path


def corner_cityjson(root: Path, *, version: str = "2.0", transform: bool = True, window: bool = True,
                    template: bool = False) -> Path:
    """The corner as CityJSON: ``ground`` (a MultiSurface, LandUse) and ``wall`` (a MultiSurface
    WallSurface with a window hole, and the Window), integer millimetres."""
    verts: dict = {}

    def idx(p):
        key = tuple(int(round(c * 1000)) for c in p)
        return verts.setdefault(key, len(verts))

    hole = [[-1, 10, 2], [-1, 10, 4], [1, 10, 4], [1, 10, 2]]         # clockwise seen from -y
    wall = [[idx(p) for p in WALL]] + ([[idx(p) for p in hole]] if window else [])
    surfaces = [wall] + ([[[idx(p) for p in hole[::-1]]]] if window else [])
    geom = {"type": "MultiSurface", "lod": "3", "boundaries": surfaces,
            "semantics": {"surfaces": [{"type": "WallSurface"}, {"type": "Window"}],
                          "values": [0, 1] if window else [0]}}
    objects = {"ground": {"type": "LandUse", "geometry": [
        {"type": "MultiSurface", "lod": "1", "boundaries": [[[idx(p) for p in GROUND]]]}]},
        "house": {"type": "Building", "geometry": [geom]}}
    if template:
        objects["tree"] = {"type": "SolitaryVegetationObject", "geometry": [
            {"type": "GeometryInstance", "template": 0, "boundaries": [0], "transformationMatrix": [0] * 16}]}
    doc = {"type": "CityJSON", "version": version, "CityObjects": objects, "vertices": [list(k) for k in verts]}
    if transform:
        doc["transform"] = {"scale": [0.001] * 3, "translate": ORIGIN.tolist()}
    path = root / "corner.city.json"
    path.write_text(json.dumps(doc))
    return path


def corner_glb(root: Path, *, origin=ORIGIN) -> Path:
    """The corner as a GLB (+y up, as exporters write it; float32 positions, as glTF stores them)
    with materials ``ground`` and ``wall``, its vertices at ``origin`` + the local corner."""
    import trimesh

    scene = trimesh.Scene()
    for i, (name, quad) in enumerate((("ground", GROUND), ("wall", WALL))):
        v = (np.array(quad, float) + origin) @ np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]]).T   # z up -> y up
        mesh = trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)
        mesh.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(name=name))
        scene.add_geometry(mesh, node_name=f"node{i}", geom_name=f"geom{i}")
    path = root / "corner.glb"
    path.write_bytes(scene.export(file_type="glb"))
    return path


def labelled_ply(root: Path, table: dict) -> Path:
    """The corner as an ASCII PLY (double coordinates) with a face property ``label`` (ground 0,
    wall 1) and the label table ``table`` beside it."""
    verts = np.array(GROUND + WALL, float) + ORIGIN
    faces = [([0, 1, 2, 3], 0), ([4, 5, 6, 7], 1)]
    head = ["ply", "format ascii 1.0", f"element vertex {len(verts)}", "property double x", "property double y",
            "property double z", f"element face {len(faces)}", "property list uchar int vertex_indices",
            "property int label", "end_header"]
    body = [" ".join(f"{c:.3f}" for c in v) for v in verts] + [f"{len(f)} {' '.join(map(str, f))} {lab}" for f, lab in faces]
    (root / "corner.ply").write_text("\n".join(head + body) + "\n")
    (root / "corner.labels.yaml").write_text(yaml.safe_dump(table))
    return root / "corner.ply"
