"""``city_block``: a small street as a survey delivers it (CityJSON, OBJ, COLMAP in a national grid),
and the same street as a scene folder built by hand.

The street (local metres, +z up, the local origin at the centre of its bounding box in x, y and
at its bottom in z): a road (``road``: ``TrafficArea`` x in [-30, 30], y in [-5, 5], and two
sidewalks, ``AuxiliaryTrafficArea``, to |y| = 8) between three buildings: ``b1`` (LoD3, x in
[-26, -2], 12 m high) and ``b2`` (LoD2, x in [2, 26], 15 m) on the north side (y in [8, 18]),
``b3`` (LoD3, x in [-20, 20], 9 m) on the south side (y in [-18, -8]). Every building is a
Solid with a ``GroundSurface``, a flat ``RoofSurface`` and four ``WallSurface`` s; the LoD3
buildings' street facades have ``Window`` s in holes of the wall (inner rings) and a ``Door`` in a
notch of its outer ring (a non-convex polygon).

Survey frame: the local frame shifted by :data:`ORIGIN` (Lambert-93-like easting and northing,
altitude 35 m): CityJSON 2.0 with ``transform`` (scale 1 mm, translate the street's lowest
corner in survey coordinates), its ``referenceSystem``
EPSG:2154, and the COLMAP model of four views in the same frame.

The builder writes into ``scenes/city_block/``:

- the **hand-built scene folder**: ``scene.yaml`` (``origin``: :data:`ORIGIN`, one segment per
  object and surface type, named as the converter names them: ``b1/WallSurface``), ``meshes/``
  (triangulated by hand: the walls as grid cells around the openings), ``sparse/`` (local
  frame), ``images/`` (the photographs: EXRs path-traced at the references, :data:`PHOTO_SPP`
  samples per pixel);
- the **survey delivery** in ``survey/``: ``street.city.json``, ``street.obj`` (the hand-built
  triangles and quads in survey coordinates, ``usemtl`` = segment names), ``sparse/`` (the
  cameras in survey coordinates) and ``emitters.yaml`` (the sky and sun of scene.yaml), from
  which ``python -m framework.convert`` rebuilds the folder (``docs/convert.md``).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from framework.images import write_exr
from framework.scene.write import pinhole_camera, write_colmap, write_mesh, write_scene_yaml
from scenes.cameras import focal_from_fov, look_at

#: survey coordinates (metres) of the local (0, 0, 0)
ORIGIN = (652340.0, 6862275.0, 35.0)
SCALE = 0.001                                       # CityJSON transform: integer millimetres
IMAGE, HEIGHT_PX, FOV = 96, 72, 70.0
PHOTO_SPP = 128
EMITTERS = [{"type": "constant", "radiance": [0.30, 0.35, 0.45]},
            {"type": "directional", "direction": [0.3, 0.6, -0.75], "irradiance": [3.0, 2.8, 2.5]}]
#: (x0, x1, y0, y1, height, LoD, street side +1 north / -1 south / 0 none)
BUILDINGS = {"b1": (-26.0, -2.0, 8.0, 18.0, 12.0, "3", 1),
             "b2": (2.0, 26.0, 8.0, 18.0, 15.0, "2", 0),
             "b3": (-20.0, 20.0, -18.0, -8.0, 9.0, "3", -1)}
#: openings of the LoD3 street facades, in facade coordinates (along the street, up), metres
WINDOW_W, WINDOW_H = 1.4, 1.4
DOOR = {"b1": (-14.6, -13.4, 2.2), "b3": (-0.6, 0.6, 2.2)}          # x0, x1, top
WINDOWS = {"b1": ([-23.0, -19.0, -10.0, -6.0], [1.0, 4.5, 8.0]),
           "b3": ([-16.0, -11.0, -6.0, 6.0, 11.0, 16.0], [1.0, 5.0])}
REFERENCES = {  # segment: {kernel: rgb}
    "b1/WallSurface": {"diffuse": [0.62, 0.55, 0.45]}, "b1/RoofSurface": {"diffuse": [0.25, 0.18, 0.15]},
    "b1/GroundSurface": {"diffuse": 0.3}, "b1/Door": {"diffuse": [0.35, 0.20, 0.10]},
    "b1/Window": {"diffuse": [0.10, 0.12, 0.14], "specular": 0.6},
    "b2/WallSurface": {"diffuse": [0.75, 0.74, 0.70]}, "b2/RoofSurface": {"diffuse": [0.20, 0.20, 0.22]},
    "b2/GroundSurface": {"diffuse": 0.3},
    "b3/WallSurface": {"diffuse": [0.50, 0.42, 0.38]}, "b3/RoofSurface": {"diffuse": [0.30, 0.25, 0.20]},
    "b3/GroundSurface": {"diffuse": 0.3}, "b3/Door": {"diffuse": [0.20, 0.25, 0.35]},
    "b3/Window": {"diffuse": [0.12, 0.12, 0.12], "specular": 0.5},
    "road/TrafficArea": {"diffuse": [0.18, 0.18, 0.18]}, "road/AuxiliaryTrafficArea": {"diffuse": [0.40, 0.38, 0.35]},
}


# ----------------------------------------------------------------------------------------------
# The street as surfaces: (object, semantic type, rings of 3D points, outer first, CCW outward)
# ----------------------------------------------------------------------------------------------

def _rect(x0, x1, y0, y1, z) -> np.ndarray:
    """A horizontal rectangle, counter-clockwise seen from above."""
    return np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], float)


def _facade_axes(b: str):
    """(point at facade x = 0, z = 0; along-street unit u; outward normal) of a street facade:
    u x up is the outward normal, so rings counter-clockwise in (u, z) face the street."""
    x0, x1, y0, y1, _, _, side = BUILDINGS[b]
    if side == 1:
        return np.array([0.0, y0, 0.0]), np.array([1.0, 0, 0])
    return np.array([0.0, y1, 0.0]), np.array([-1.0, 0, 0])


def _on_facade(b: str, pts2d) -> np.ndarray:
    """Facade coordinates (x along the street in world x, z up) to 3D points on ``b``'s facade."""
    base, _ = _facade_axes(b)
    return np.array([[x, base[1], z] for x, z in pts2d], float)


def _ccw(b: str, ring2d: list, outward: bool = True) -> list:
    """``ring2d`` in world (x, z), ordered so its normal points out of the facade (or in)."""
    _, u = _facade_axes(b)
    ring = ring2d if u[0] > 0 else ring2d[::-1]
    return ring if outward else ring[::-1]


def openings(b: str) -> list[tuple[float, float, float, float]]:
    """Windows of ``b``'s street facade as (x0, x1, z0, z1), world x."""
    if b not in WINDOWS:
        return []
    xs, zs = WINDOWS[b]
    return [(x - WINDOW_W / 2, x + WINDOW_W / 2, z, z + WINDOW_H) for z in zs for x in xs]


def surfaces() -> list[tuple[str, str, list[np.ndarray]]]:
    """Every surface of the street: (object id, semantic type, rings) in local metres."""
    out = [("road", "TrafficArea", [_rect(-30, 30, -5, 5, 0)]),
           ("road", "AuxiliaryTrafficArea", [_rect(-30, 30, 5, 8, 0)]),
           ("road", "AuxiliaryTrafficArea", [_rect(-30, 30, -8, -5, 0)])]
    for b, (x0, x1, y0, y1, h, _, side) in BUILDINGS.items():
        out.append((b, "GroundSurface", [_rect(x0, x1, y0, y1, 0)[::-1]]))
        out.append((b, "RoofSurface", [_rect(x0, x1, y0, y1, h)]))
        corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
        for (ax, ay), (bx, by) in zip(corners, corners[1:] + corners[:1]):
            wall = np.array([[ax, ay, 0], [bx, by, 0], [bx, by, h], [ax, ay, h]], float)
            street = side != 0 and ((side == 1 and ay == by == y0) or (side == -1 and ay == by == y1))
            if not street:
                out.append((b, "WallSurface", [wall]))
                continue
            out += _lod3_facade(b, x0, x1, h)
    return out


def _lod3_facade(b: str, x0: float, x1: float, h: float) -> list:
    """The street facade of ``b``: a wall with a door notch and window holes, the windows, the door."""
    d0, d1, dtop = DOOR[b]
    outer = _ccw(b, [(x0, 0), (d0, 0), (d0, dtop), (d1, dtop), (d1, 0), (x1, 0), (x1, h), (x0, h)])
    holes = [_ccw(b, [(a, c), (bb, c), (bb, d), (a, d)], outward=False) for a, bb, c, d in openings(b)]
    out = [(b, "WallSurface", [_on_facade(b, outer)] + [_on_facade(b, r) for r in holes])]
    out += [(b, "Window", [_on_facade(b, _ccw(b, [(a, c), (bb, c), (bb, d), (a, d)]))]) for a, bb, c, d in openings(b)]
    out.append((b, "Door", [_on_facade(b, _ccw(b, [(d0, 0), (d1, 0), (d1, dtop), (d0, dtop)]))]))
    return out


# ----------------------------------------------------------------------------------------------
# By hand: triangles and quads per segment (no earcut: walls as grid cells around the openings)
# ----------------------------------------------------------------------------------------------

def hand_polygons() -> dict[str, list[np.ndarray]]:
    """Segment -> convex polygons (quads, (4, 3) arrays, outward CCW) covering its surfaces."""
    out: dict[str, list[np.ndarray]] = {}
    for obj, sem, rings in surfaces():
        name = f"{obj}/{sem}"
        if len(rings) == 1 and len(rings[0]) == 4:
            out.setdefault(name, []).append(rings[0])
        else:                                   # an LoD3 facade: grid cells outside the openings
            out.setdefault(name, []).extend(_wall_cells(obj))
    return out


def _wall_cells(b: str) -> list[np.ndarray]:
    x0, x1, _, _, h, _, _ = BUILDINGS[b]
    d0, d1, dtop = DOOR[b]
    holes = openings(b) + [(d0, d1, 0.0, dtop)]
    xs = np.unique([x0, x1] + [v for r in holes for v in r[:2]])
    zs = np.unique([0.0, h] + [v for r in holes for v in r[2:]])
    cells = []
    for a, bb in zip(xs[:-1], xs[1:]):
        for c, d in zip(zs[:-1], zs[1:]):
            if any(r[0] < (a + bb) / 2 < r[1] and r[2] < (c + d) / 2 < r[3] for r in holes):
                continue
            cells.append(_on_facade(b, _ccw(b, [(a, c), (bb, c), (bb, d), (a, d)])))
    return cells


def _triangles(quads: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Quads as one mesh of two triangles each (convex: the fan is right)."""
    v = np.concatenate(quads)
    f = np.concatenate([[[4 * i, 4 * i + 1, 4 * i + 2], [4 * i, 4 * i + 2, 4 * i + 3]] for i in range(len(quads))])
    return v, f


def cameras(width: int = IMAGE, height: int = HEIGHT_PX) -> list:
    """Four views in the local frame: three along the street, one from above the south side."""
    f = focal_from_fov(width, FOV)
    poses = [([-14.0, -3.0, 1.7], [-14.0, 8.0, 4.5]), ([14.0, -3.0, 1.7], [14.0, 8.0, 5.5]),
             ([0.0, 4.0, 1.7], [0.0, -8.0, 3.5]), ([0.0, -32.0, 28.0], [0.0, 4.0, 3.0])]
    return [pinhole_camera(f"view_{i:03d}.png", width, height, f, look_at(eye, target))
            for i, (eye, target) in enumerate(poses)]


def shifted(cams: list, origin) -> list:
    """The same views with the world shifted by ``origin`` (float64): t' = t - R·origin."""
    from dataclasses import replace

    o = np.asarray(origin, np.float64)
    return [replace(c, cam_from_world=np.concatenate(
        [c.cam_from_world[:, :3], (c.cam_from_world[:, 3] - c.cam_from_world[:, :3] @ o)[:, None]], 1)) for c in cams]


# ----------------------------------------------------------------------------------------------
# Writers
# ----------------------------------------------------------------------------------------------

def write_handbuilt(folder: Path, *, width: int = IMAGE, height: int = HEIGHT_PX) -> Path:
    """The hand-built scene folder (no ``images/``: observations from the references)."""
    folder = Path(folder)
    segments = []
    for name, quads in hand_polygons().items():
        rel = f"meshes/{name.replace('/', '_')}.ply"
        write_mesh(folder / rel, *_triangles(quads))
        ref = REFERENCES[name]
        segments.append({"name": name, "meshes": [rel], "kernels": list(ref), "reference": ref})
    write_colmap(folder / "sparse", cameras(width, height), np.array(_landmarks()))
    scene = {"name": folder.name, "channels": "rgb", "origin": list(ORIGIN), "segments": segments,
             "emitters": EMITTERS}
    write_scene_yaml(folder / "scene.yaml", scene, _comment())
    return folder


def _landmarks() -> list:
    return [[x0, y, 0.0] for x0, x1, y0, y1, h, _, _ in BUILDINGS.values() for y in (y0, y1)]


def write_cityjson(path: Path) -> Path:
    """``street.city.json``: CityJSON 2.0, integer millimetres with ``transform``, survey frame."""
    vertices: dict[tuple[int, int, int], int] = {}
    low = np.min([p for _, _, rings in surfaces() for ring in rings for p in ring], axis=0)

    def index(p) -> int:                # integer millimetres from the street's lowest corner
        key = tuple(int(round(c / SCALE)) for c in np.asarray(p) - low)
        return vertices.setdefault(key, len(vertices))

    objects: dict[str, dict] = {}
    for obj, sem, rings in surfaces():
        o = objects.setdefault(obj, {"types": [], "surfaces": [], "values": []})
        if sem not in o["types"]:
            o["types"].append(sem)
        o["surfaces"].append([[index(p) for p in ring] for ring in rings])
        o["values"].append(o["types"].index(sem))
    city = {}
    for obj, o in objects.items():
        semantics = {"surfaces": [{"type": t} for t in o["types"]], "values": o["values"]}
        if obj == "road":
            geom = {"type": "MultiSurface", "lod": "2", "boundaries": o["surfaces"], "semantics": semantics}
            city[obj] = {"type": "Road", "geometry": [geom]}
        else:
            semantics["values"] = [o["values"]]
            geom = {"type": "Solid", "lod": BUILDINGS[obj][5], "boundaries": [o["surfaces"]], "semantics": semantics}
            city[obj] = {"type": "Building", "attributes": {"measuredHeight": BUILDINGS[obj][4]}, "geometry": [geom]}
    translate = [float(x) for x in np.asarray(ORIGIN) + low]
    doc = {"type": "CityJSON", "version": "2.0",
           "transform": {"scale": [SCALE] * 3, "translate": translate},
           "metadata": {"referenceSystem": "https://www.opengis.net/def/crs/EPSG/0/2154",
                        "title": "city_block: a small street (scenes/city_block.py)"},
           "CityObjects": city, "vertices": [list(k) for k in vertices]}
    path.write_text(json.dumps(doc, separators=(",", ":")) + "\n", encoding="utf-8")
    return path


def write_obj(path: Path) -> Path:
    """``street.obj``: the hand-built quads (4-vertex faces) per ``usemtl`` segment, survey frame."""
    o = np.asarray(ORIGIN)
    lines = ["# city_block (scenes/city_block.py): survey coordinates, one usemtl per segment"]
    faces, n = [], 0
    for name, quads in hand_polygons().items():
        faces.append(f"usemtl {name}")
        for q in quads:
            lines += [f"v {x:.3f} {y:.3f} {z:.3f}" for x, y, z in q + o]
            faces.append("f " + " ".join(str(n + k + 1) for k in range(4)))
            n += 4
    path.write_text("\n".join(lines + faces) + "\n", encoding="utf-8")
    return path


def build(folder: Path, *, width: int = IMAGE, height: int = HEIGHT_PX, spp: int = PHOTO_SPP) -> Path:
    """Write ``folder`` (the hand-built scene with its photographs) and ``folder/survey``."""
    from framework.observe import render_references
    from framework.render.backend import set_variant
    from framework.scene import load_scene

    folder = Path(folder)
    write_handbuilt(folder, width=width, height=height)
    scene = load_scene(folder)
    set_variant("auto", channels=scene.channels)
    (folder / "images").mkdir(exist_ok=True)
    for cam, img in zip(scene.cameras, render_references(scene, list(scene.cameras), spp=spp, max_depth=-1, seed=0)):
        write_exr(folder / "images" / Path(cam.name).with_suffix(".exr"), img, ("R", "G", "B"))
    survey = folder / "survey"
    survey.mkdir(parents=True, exist_ok=True)
    write_cityjson(survey / "street.city.json")
    write_obj(survey / "street.obj")
    write_colmap(survey / "sparse", shifted(cameras(width, height), ORIGIN), np.array(_landmarks()) + ORIGIN)
    write_scene_yaml(survey / "emitters.yaml", {"channels": "rgb", "emitters": EMITTERS},
                     "The street's illumination, for python -m framework.convert --emitters (docs/convert.md).")
    return folder


def _comment() -> str:
    return """Generated by `python -m scenes.build city_block` (scenes/city_block.py); do not edit by hand.
A small street by hand, local frame: origin is where its (0, 0, 0) lies in the survey (EPSG:2154-like).
survey/ holds the same street as delivered (CityJSON, OBJ, COLMAP in survey coordinates); docs/convert.md
converts it back into a folder like this one. Photographs: images/, path-traced at the references."""
