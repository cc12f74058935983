"""``street_block``: the ``urban_canyon`` street cut into K buildings per side, each with its own materials.

Geometry, illumination and views are :mod:`scenes.urban_canyon`'s (the 40 m street, the baked
sky and the sun, its eight street views and the aerial view); only the segmentation changes.
Each side's facade is cut along the street (x) into ``K`` buildings of equal width
``40 m / K``: every element of the side (the wall with its recess sides, end and back walls,
the window glass, the balconies, the awnings and the roof) is clipped at the building
boundaries, so a boundary may run through a window or a balcony, whose two parts then belong
to two buildings.

Materials: each building has its own ``wall``, ``window``, ``balcony`` and ``awning``
segments (kernels ``[diffuse, specular]``), with references drawn from a seeded generator in
plausible ranges (:data:`MATERIALS`) with ρ_d + ρ_s ≤ 1 per channel. The ``roof`` (one
segment, one file per building) and the ``asphalt`` are shared, with ``urban_canyon``'s
references. A building that holds no part of an element (a 2.5 m building between two
balconies, at K = 16) has no segment for it, so a scene has at most ``8 K + 2`` materials
(``D = 16 K + 4`` unknowns). K = 1 is ``urban_canyon``'s layout with one material per element
and side: its facade meshes are ``urban_canyon``'s own files.

Segments are named ``<side><building>_<element>`` (``north00_wall``, buildings numbered from
x = -20 m) and their meshes ``meshes/<segment>.ply``; the roof's are ``meshes/<side><building>_roof.ply``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from framework.scene.write import write_colmap, write_scene_yaml
from scenes import geometry as g
from scenes import urban_canyon as uc

#: The elements that every building has its own material for, in segment order.
ELEMENTS = ("wall", "window", "balcony", "awning")

#: element: (albedo range, per-channel tint, specular range) of the drawn references. The
#: diffuse colour is an albedo times (1 ± tint) per channel; the specular weight is grey.
MATERIALS = {
    "wall": ((0.35, 0.80), 0.15, (0.00, 0.10)),
    "window": ((0.08, 0.25), 0.15, (0.50, 0.75)),
    "balcony": ((0.15, 0.55), 0.15, (0.00, 0.05)),
    "awning": ((0.05, 0.50), 0.80, (0.00, 0.05)),
}

#: Vertices this close to a building boundary (metres) lie on it.
EPS = 1e-9


def building_edges(buildings: int) -> np.ndarray:
    """The x of the building boundaries along the street, ends included.

    Parameters
    ----------
    buildings : int
        Buildings per side, K >= 1.

    Returns
    -------
    ndarray, shape (K + 1,)
        From -20 m to 20 m in equal steps.
    """
    if buildings < 1:
        raise ValueError(f"buildings={buildings}: use at least one building per side")
    return np.linspace(-uc.LENGTH / 2, uc.LENGTH / 2, buildings + 1)


def _half(poly: np.ndarray, d: np.ndarray) -> g.Mesh:
    """The part of a convex polygon where the signed distance ``d`` is <= 0, as a triangle fan.

    Parameters
    ----------
    poly : ndarray, shape (k, 3)
        Vertices in order (the polygon's winding is kept).
    d : ndarray, shape (k,)
        Signed distances of the vertices to the cutting plane (0 on it).

    Returns
    -------
    Mesh
        The fan (0, i, i + 1) of the clipped polygon; no face if less than a triangle remains.
    """
    out, k = [], len(poly)
    for i, j in zip(range(k), [*range(1, k), 0]):
        if d[i] <= 0:
            out.append(poly[i])
        if d[i] * d[j] < 0:
            out.append(poly[i] + d[i] / (d[i] - d[j]) * (poly[j] - poly[i]))
    faces = [[0, i, i + 1] for i in range(1, len(out) - 1)]
    return np.array(out).reshape(-1, 3), np.array(faces, int).reshape(-1, 3)


def split_x(mesh: g.Mesh, x: float) -> tuple[g.Mesh, g.Mesh]:
    """Cut a mesh by the plane at ``x`` into its parts below and above ``x``.

    Triangles across the plane are clipped (windings kept). A triangle lying in the plane goes
    to the side opposite its normal: it bounds the solid on that side (a box's end face).

    Parameters
    ----------
    mesh : Mesh
        Vertices and faces.
    x : float
        The plane's abscissa.

    Returns
    -------
    (Mesh, Mesh)
        The parts with x <= ``x`` and with x >= ``x``; either may have no face.
    """
    v, f = mesh
    d = v[f][:, :, 0] - x
    d[np.abs(d) <= EPS] = 0.0
    planar = (d == 0).all(axis=1)
    n_x = g.face_normals(mesh)[:, 0] if len(f) else np.zeros(0)
    below = np.where(planar, n_x > 0, (d <= 0).all(axis=1))
    above = np.where(planar, n_x < 0, (d >= 0).all(axis=1))
    cross = np.flatnonzero(~below & ~above)
    parts = []
    for sign, keep in ((1.0, below), (-1.0, above)):
        clipped = [_half(v[f[t]], sign * d[t]) for t in cross]
        parts.append(g.compact(g.merge([(v, f[keep]), *clipped])))
    return parts[0], parts[1]


def strips(mesh: g.Mesh, buildings: int) -> list[g.Mesh]:
    """The parts of ``mesh`` in each of the ``buildings`` strips of :func:`building_edges`.

    Parameters
    ----------
    mesh : Mesh
        An element of one side (it lies within x in [-20, 20] m).
    buildings : int
        K; with K = 1 the mesh is returned as it is.

    Returns
    -------
    list of Mesh
        K meshes, west (x = -20 m) to east; a strip the element misses has no face.
    """
    out, rest = [], mesh
    for x in building_edges(buildings)[1:-1]:
        part, rest = split_x(rest, x)
        out.append(part)
    return out + [rest]


def building_meshes(buildings: int) -> dict[str, list[tuple[str, g.Mesh]]]:
    """Segment name -> [(mesh file stem, mesh)]: the buildings' elements, then roof and asphalt.

    Parameters
    ----------
    buildings : int
        K buildings per side.

    Returns
    -------
    dict
        ``<side><k>_<element>`` for each side, building and element the building holds part of
        (its one file has the segment's name), then ``roof`` (one file per building) and
        ``asphalt``.
    """
    out: dict[str, list] = {}
    roofs = []
    for side, tag in uc.SIDES:
        elements = {name: strips(mesh, buildings) for name, mesh in uc.side_meshes(side).items()}
        for k in range(buildings):
            for name in ELEMENTS:
                if len(elements[name][k][1]):
                    out[f"{tag}{k:02d}_{name}"] = [(f"{tag}{k:02d}_{name}", elements[name][k])]
            roofs.append((f"{tag}{k:02d}_roof", elements["roof"][k]))
    out["roof"] = [r for r in roofs if len(r[1][1])]
    out["asphalt"] = [("asphalt", uc.ground())]
    return out


def draw_reference(rng: np.random.Generator, element: str) -> dict:
    """A random rgb reference of ``element`` in the ranges of :data:`MATERIALS`.

    Parameters
    ----------
    rng : numpy.random.Generator
        The draws (four numbers per call).
    element : str
        A key of :data:`MATERIALS`.

    Returns
    -------
    dict
        ``diffuse``: 3 values, ``specular``: one value, all in [0, 1] with 3 decimals and
        diffuse + specular <= 1 in every channel.
    """
    (a0, a1), tint, (s0, s1) = MATERIALS[element]
    albedo, tints, spec = rng.uniform(a0, a1), rng.uniform(-tint, tint, 3), rng.uniform(s0, s1)
    spec = round(float(spec), 3)
    diffuse = np.clip(np.round(albedo * (1 + tints), 3), 0.01, round(1 - spec, 3))
    return {"diffuse": [float(x) for x in diffuse], "specular": spec}


def references(buildings: int, seed: int) -> dict[str, dict]:
    """Segment name -> reference of every building element, roof and asphalt.

    Building ``k`` of side ``s`` draws its four materials from its own generator
    ``default_rng([seed, s, k])`` (s = 0 north, 1 south), whichever elements it holds.

    Parameters
    ----------
    buildings : int
        K buildings per side.
    seed : int
        The materials' seed (>= 0).

    Returns
    -------
    dict
        ``<side><k>_<element>`` for all sides, buildings and elements, plus ``roof`` and
        ``asphalt`` (``urban_canyon``'s rgb references).
    """
    out = {}
    for s, (_, tag) in enumerate(uc.SIDES):
        for k in range(buildings):
            rng = np.random.default_rng([seed, s, k])
            out.update({f"{tag}{k:02d}_{e}": draw_reference(rng, e) for e in ELEMENTS})
    for name in ("roof", "asphalt"):
        rgb_d, rgb_s = uc.REFERENCES[name][:2]
        out[name] = {"diffuse": rgb_d, "specular": rgb_s}
    return out


def build(folder: Path, buildings: int = 2, seed: int = 0, *, n_street: int = 8, image: int = uc.IMAGE) -> Path:
    """Write the scene folder: ``urban_canyon`` with K buildings per side (rgb).

    Parameters
    ----------
    folder : Path
        Output folder (created; existing files are overwritten, others left).
    buildings : int
        K buildings per side (1, 2, 4, 8, 16 ...).
    seed : int
        Seed of the buildings' materials; the same arguments write the same bytes.
    n_street, image : int
        Street views and image width and height (:func:`scenes.urban_canyon.cameras`); the
        defaults give ``urban_canyon``'s nine 200 x 200 views.

    Returns
    -------
    Path
        ``folder``.
    """
    folder = Path(folder)
    refs = references(buildings, seed)
    segs = [{"name": name, "meshes": uc.write_mesh_files(folder, parts), "kernels": ["diffuse", "specular"],
             "reference": refs[name]} for name, parts in building_meshes(buildings).items()]
    emitters = uc.write_lighting(folder, "rgb")
    write_colmap(folder / "sparse", uc.cameras(n_street, image), uc.landmarks())
    scene = {"name": folder.name, "channels": "rgb", "segments": segs, "emitters": emitters}
    write_scene_yaml(folder / "scene.yaml", scene, _comment(buildings, seed, len(segs)))
    return folder


def _comment(buildings: int, seed: int, materials: int) -> str:
    """The provenance block of ``scene.yaml``."""
    return f"""Generated by scenes/street_block.py (build(buildings={buildings}, seed={seed})); do not edit by hand.
The urban_canyon street (same geometry, sky, sun and views) cut into {buildings} building(s) per side,
each with its own wall, window, balcony and awning materials drawn from seed {seed};
roof and asphalt are shared. {materials} materials x [diffuse, specular] = {2 * materials} unknowns.
Units: radiance W m^-2 sr^-1 nm^-1 (irradiance W m^-2 nm^-1), Mitsuba sunsky's own, scale 1."""
