"""``urban_canyon``: a street between two facades, after the paper's figure 4 (section 5.1).

Geometry (metres, +z up): a street 40 m long along x (x in [-20, 20]) and 10 m wide
(y in [-5, 5]) between two buildings 15 m high and 10 m deep. Each facade has a shop floor
(recessed shop windows under tilted awnings) and three upper floors of recessed windows
(0.2 m deep; the glass at the back of the recess is ``window``, the recess sides are ``wall``),
with balconies protruding 1.2 m on every other column. The ground (``asphalt``) is a
120 m x 80 m plane. Roofs are the flat building tops.

Illumination: Mitsuba's ``sunsky`` (turbidity 3) baked without its sun into ``sky.exr``
(see :mod:`scenes.sky`), plus the sun as a ``directional`` emitter at elevation 45°, azimuth
245° (from +y towards +x): the north facade (y = +5, facing -y) is lit, the south facade is in
shadow, and the south building's shadow covers about 6 m of the 10 m street.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from framework.images import write_exr
from framework.scene import Camera
from framework.scene.write import pinhole_camera, write_colmap, write_mesh, write_scene_yaml
from scenes import geometry as g
from scenes.cameras import focal_from_fov, look_at
from scenes.sky import bake_sky, sun_irradiance, sun_vector

LENGTH, HALF_WIDTH, DEPTH, HEIGHT = 40.0, 5.0, 10.0, 15.0
COLUMNS = np.arange(-18.0, 18.1, 4.0)             # window column centres (x)
FLOORS = (4.0, 7.0, 10.0)                         # upper floor levels (z)
RECESS, BALCONY_DEPTH = 0.2, 1.2
SHOP = (1.3, 0.4, 3.0)                            # half width, bottom, top of a shop window
UPPER = (0.7, 0.6, 2.4)                           # half width, sill and lintel above the floor
SUN_ELEVATION, SUN_AZIMUTH, TURBIDITY = 45.0, 245.0, 3.0
SKY_SIZE = (64, 128)
IMAGE, FOV = 200, 65.0
SIDES = ((1, "north"), (-1, "south"))             # (side, tag) of the two buildings

REFERENCES = {  # name: (rgb diffuse, rgb specular, Table 2 diffuse, Table 2 specular)
    "roof": ([0.24, 0.19, 0.17], 0.0, 0.2, 0.0),
    "wall": ([0.74, 0.72, 0.66], 0.08, 0.72, 0.08),
    "balcony": ([0.32, 0.30, 0.27], 0.0, 0.3, 0.0),
    "asphalt": ([0.20, 0.19, 0.18], 0.0, 0.2, 0.0),
    "awning": ([0.10, 0.03, 0.03], 0.0, 0.05, 0.0),
    "window": ([0.16, 0.18, 0.20], 0.72, 0.18, 0.72),
}


def window_rects() -> list[tuple[float, float, float, float]]:
    """Facade openings as (x0, x1, z0, z1): one shop window and three upper windows per column."""
    rects = [(x - SHOP[0], x + SHOP[0], SHOP[1], SHOP[2]) for x in COLUMNS]
    rects += [(x - UPPER[0], x + UPPER[0], f + UPPER[1], f + UPPER[2]) for f in FLOORS for x in COLUMNS]
    return rects


def _facade_frame(side: int):
    """(point on facade, outward normal, along-street axis) for side +1 (north) or -1 (south)."""
    return np.array([0.0, side * HALF_WIDTH, 0.0]), np.array([0.0, -side, 0.0]), np.array([1.0, 0, 0])


def _at(side: int, x: float, z: float, out: float = 0.0) -> np.ndarray:
    """World point at street coordinate x, height z, ``out`` metres in front of a facade."""
    return np.array([x, side * (HALF_WIDTH - out), z])


def _oriented_quad(side: int, origin, eu, ev) -> g.Mesh:
    """Quad whose normal faces the street for the facade ``side`` (flipped if needed)."""
    mesh = g.quad(origin, eu, ev)
    want = _facade_frame(side)[1]
    n = np.cross(eu, ev)
    if abs(np.dot(n, want)) > 1e-9 and np.dot(n, want) < 0:
        return g.flip(mesh)
    return mesh


def facade_wall(side: int) -> g.Mesh:
    """The facade plane with holes at the openings, as a grid of wall cells."""
    rects = window_rects()
    xs = np.unique([-LENGTH / 2, LENGTH / 2] + [v for r in rects for v in r[:2]])
    zs = np.unique([0.0, HEIGHT] + [v for r in rects for v in r[2:]])
    cells = []
    for x0, x1 in zip(xs[:-1], xs[1:]):
        for z0, z1 in zip(zs[:-1], zs[1:]):
            xc, zc = (x0 + x1) / 2, (z0 + z1) / 2
            if any(r[0] < xc < r[1] and r[2] < zc < r[3] for r in rects):
                continue
            cells.append(_oriented_quad(side, _at(side, x0, z0), [x1 - x0, 0, 0], [0, 0, z1 - z0]))
    return g.merge(cells)


def recesses(side: int) -> tuple[g.Mesh, g.Mesh]:
    """(recess sides, glass) of every opening; the glass lies ``RECESS`` behind the facade."""
    sides, glass = [], []
    inward = np.array([0.0, side * RECESS, 0.0])
    for x0, x1, z0, z1 in window_rects():
        a, b = _at(side, x0, z0), _at(side, x1, z0)
        c, d = _at(side, x1, z1), _at(side, x0, z1)
        centre = (a + c) / 2 + inward / 2
        for p, q in ((a, b), (b, c), (c, d), (d, a)):
            sides.append(g.orient_towards(g.quad(p, q - p, inward), centre))
        glass.append(_oriented_quad(side, a + inward, b - a, d - a))
    return g.merge(sides), g.merge(glass)


def balconies(side: int) -> g.Mesh:
    """Balconies on every other column of the upper floors: slab and three parapets."""
    parts, out = [], np.array([0.0, -side, 0.0])
    for f in FLOORS:
        for x in COLUMNS[1::2]:
            o = _at(side, x - 1.0, f - 0.15, out=-0.01)
            w, d = np.array([2.0, 0, 0]), out * (BALCONY_DEPTH + 0.01)
            parts.append(g.box(o, w, d, [0, 0, 0.15]))                          # slab
            front = o + d - out * 0.08 + [0, 0, 0.15]
            parts.append(g.box(front, w, out * 0.08, [0, 0, 1.0]))              # front parapet
            for xs in (0.0, 1.92):
                parts.append(g.box(o + [xs, 0, 0.15], [0.08, 0, 0], d - out * 0.08, [0, 0, 1.0]))
    return g.merge(parts)


def awnings(side: int) -> g.Mesh:
    """Tilted awnings over the shop windows: 1.5 m out, dropping from 3.3 m to 2.8 m."""
    out = np.array([0.0, -side, 0.0])
    return g.merge([g.box(_at(side, x - 1.5, 3.3), [3.0, 0, 0], out * 1.5 + [0, 0, -0.5], [0, 0, 0.04])
                    for x in COLUMNS])


def building_shell(side: int) -> tuple[g.Mesh, g.Mesh]:
    """(end and back walls, flat roof) of the building behind facade ``side``."""
    box = g.aabox([-LENGTH / 2, min(side * HALF_WIDTH, side * (HALF_WIDTH + DEPTH)), 0.0],
                  [LENGTH / 2, max(side * HALF_WIDTH, side * (HALF_WIDTH + DEPTH)), HEIGHT])
    v, f = box
    normals = g.face_normals(box)
    keep_walls = (np.abs(normals[:, 2]) < 0.5) & (normals[:, 1] * side >= -0.5)   # not facade/top/bottom
    roof = normals[:, 2] > 0.5
    return g.compact((v, f[keep_walls])), g.compact((v, f[roof]))


def ground() -> g.Mesh:
    """The asphalt: a 120 m x 80 m plane at z = 0, facing up."""
    return g.quad([-60.0, -40.0, 0.0], [120.0, 0, 0], [0, 80.0, 0])


def side_meshes(side: int) -> dict[str, g.Mesh]:
    """The building behind facade ``side`` (+1 north, -1 south) by element.

    Parameters
    ----------
    side : int
        +1 for the north building (facade at y = +5), -1 for the south one.

    Returns
    -------
    dict of str to Mesh
        ``wall`` (facade with openings, recess sides, end and back walls), ``roof``,
        ``window`` (the glass), ``balcony`` and ``awning``, in that order.
    """
    walls, roof = building_shell(side)
    sides, glass = recesses(side)
    return {"wall": g.merge([facade_wall(side), sides, walls]), "roof": roof, "window": glass,
            "balcony": balconies(side), "awning": awnings(side)}


def meshes() -> dict[str, list[tuple[str, g.Mesh]]]:
    """Segment name -> [(mesh file stem, mesh)], one file per building and part."""
    out: dict[str, list] = {k: [] for k in REFERENCES}
    for side, tag in SIDES:
        for element, mesh in side_meshes(side).items():
            out[element].append((f"{element}_{tag}", mesh))
    out["asphalt"].append(("asphalt", ground()))
    return out


def street_view(i: int, n_street: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """(eye, target) of street view ``i`` of ``n_street``: a mapping vehicle 2.5 m up on the centre line.

    The views are evenly spaced along x in [-14, 14] m (every 4 m for the bundled eight),
    alternate facades (even ``i``: north), and look 6 m ahead (+x) in the first half, 6 m back
    in the second, at 4.5 m up on the facade: eye and target stay within the facades' extent.
    """
    step = 28.0 / (n_street - 1) if n_street > 1 else 0.0
    x, side, ahead = -14.0 + step * i, 1 if i % 2 == 0 else -1, 6.0 if i < n_street / 2 else -6.0
    return np.array([x, 0.0, 2.5]), np.array([x + ahead, side * HALF_WIDTH, 4.5])


def cameras(n_street: int = 8, image: int = IMAGE) -> list[Camera]:
    """``n_street`` street views (:func:`street_view`) and one aerial view, ``image`` x ``image`` pixels.

    The defaults give the bundled scene's nine views; more street views (e.g. 15, for 16 views in
    all) continue the same pattern at a closer spacing.
    """
    if n_street < 1:
        raise ValueError(f"n_street={n_street}: use at least one street view")
    focal = focal_from_fov(image, FOV)
    views = [pinhole_camera(f"street_{i:03d}.png", image, image, focal, look_at(*street_view(i, n_street)))
             for i in range(n_street)]
    views.append(pinhole_camera("aerial_000.png", image, image, focal,
                                look_at([-6.0, -24.0, 38.0], [0.0, 3.0, 2.0])))
    return views


def landmarks() -> np.ndarray:
    """A few scene points for points3D.txt: the top and bottom corners of both facades."""
    return np.array([[x, y, z] for y in (-HALF_WIDTH, HALF_WIDTH) for x in (-20.0, 20.0) for z in (0.0, HEIGHT)])


def segments(channels: str, files: dict[str, list[str]]) -> list[dict]:
    """scene.yaml ``segments``: rgb colour variants, or the paper's Table 2 values for mono."""
    out = []
    for name, (rgb_d, rgb_s, mono_d, mono_s) in REFERENCES.items():
        ref = {"diffuse": rgb_d, "specular": rgb_s} if channels == "rgb" else {"diffuse": mono_d, "specular": mono_s}
        out.append({"name": name, "meshes": files[name], "kernels": ["diffuse", "specular"], "reference": ref})
    return out


def build(folder: Path, channels: str = "rgb", *, n_street: int = 8, image: int = IMAGE) -> Path:
    """Write the scene folder (``channels``: ``rgb`` or ``mono``, the 550 nm band).

    ``n_street`` and ``image`` give a variant with other street views or image size (see
    :func:`cameras`; the benchmark's 16-view scenes); the defaults write the bundled scene.
    """
    folder = Path(folder)
    files = {seg: write_mesh_files(folder, parts) for seg, parts in meshes().items()}
    emitters = write_lighting(folder, channels)
    write_colmap(folder / "sparse", cameras(n_street, image), landmarks())
    scene = {"name": folder.name, "channels": channels, "segments": segments(channels, files),
             "emitters": emitters}
    write_scene_yaml(folder / "scene.yaml", scene, _comment(channels))
    return folder


def write_mesh_files(folder: Path, parts: list[tuple[str, g.Mesh]]) -> list[str]:
    """Write ``meshes/<stem>.ply`` for each (stem, mesh) of ``parts``.

    Parameters
    ----------
    folder : Path
        The scene folder.
    parts : list of (str, Mesh)
        File stems and meshes.

    Returns
    -------
    list of str
        The PLY paths relative to ``folder``, as ``scene.yaml`` lists them.
    """
    return [str(write_mesh(folder / "meshes" / f"{stem}.ply", *m).relative_to(folder)) for stem, m in parts]


def write_lighting(folder: Path, channels: str) -> list[dict]:
    """Bake the sky into ``folder/sky.exr``; the street's emitters (sky and sun) for ``scene.yaml``.

    Parameters
    ----------
    folder : Path
        The scene folder.
    channels : str
        ``rgb`` or ``mono`` (the 550 nm band).

    Returns
    -------
    list of dict
        An ``envmap`` emitter naming ``sky.exr`` and the ``directional`` sun.
    """
    sun = sun_vector(SUN_ELEVATION, SUN_AZIMUTH)
    write_exr(folder / "sky.exr", bake_sky(sun, *SKY_SIZE, channels, TURBIDITY), ("R", "G", "B") if channels == "rgb" else ("Y",))
    e_sun = sun_irradiance(sun, channels, TURBIDITY)
    return [{"type": "envmap", "file": "sky.exr", "scale": 1.0},
            {"type": "directional", "direction": (-sun).tolist(),
             "irradiance": e_sun.tolist() if channels == "rgb" else float(e_sun[0])}]


def _comment(channels: str) -> str:
    band = ("RGB (Mitsuba llvm_ad_rgb sunsky)" if channels == "rgb"
            else "the 550 nm band (sunsky evaluated in llvm_ad_spectral at 550 nm)")
    return f"""Generated by `python -m scenes.build` (scenes/urban_canyon.py); do not edit by hand.
Street canyon after the paper's figure 4 / Table 2 (section 5.1). Channels: {band}.
Units: radiance W m^-2 sr^-1 nm^-1 (irradiance W m^-2 nm^-1), Mitsuba sunsky's own, scale 1:
typical pixel values are 0.02-0.4.
sky.exr: sunsky (turbidity {TURBIDITY}, sun_scale 0) baked {SKY_SIZE[0]}x{SKY_SIZE[1]}, image top = +z;
below the horizon: a Lambertian ground of albedo 0.2 lit by the same sun and sky.
Sun: elevation {SUN_ELEVATION} deg, azimuth {SUN_AZIMUTH} deg from +y towards +x; its irradiance is sunsky's
sun disk integrated over its solid angle (sky_scale 0)."""
