"""The common model of every reader: shared float64 vertices, and faces grouped into segments.

A reader (:mod:`.obj`, :mod:`.ply`, :mod:`.gltf`, :mod:`.cityjson`) turns its source into a
:class:`Source`: the vertices as the file gives them (survey coordinates included, in float64)
and, per segment, triangles and polygons (with holes). :func:`triangulate` turns the polygons
into triangles with mapbox earcut, dropping degenerate ones (and counting them);
:func:`local_origin` and :func:`moved` move everything near the origin in float64.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from framework.errors import SceneError

#: Coordinates beyond this (metres, any axis) are survey coordinates: the converter moves the
#: geometry to a local origin. float32 (the renderer's precision) resolves 6e-5 m at 1 km and
#: 0.5 m at 6.9e6 m.
SURVEY_LIMIT = 1000.0
#: A polygon whose area is below this fraction of its squared perimeter is degenerate (a line).
DEGENERATE_RATIO = 1e-12


@dataclass
class Polygon:
    """One planar polygon: its rings as vertex indices into :attr:`Source.vertices`, the outer
    ring first, then the holes (CityJSON's ``[[outer], [hole], ...]``)."""

    rings: list[np.ndarray]
    where: str = ""                     # where the source gives it, for messages: ``line 12``, ``surface [0, 3]``


@dataclass
class Part:
    """The faces of one segment as the source gives them."""

    name: str                           # the segment name (``b1/WallSurface``, a material, an object)
    semantic: str | None = None         # a CityJSON semantic surface type (``Window``), else None
    kind: str = "segment"               # what the source calls it, for messages: material, object, ...
    triangles: list[np.ndarray] = field(default_factory=list)    # (k, 3) int arrays
    polygons: list[Polygon] = field(default_factory=list)


@dataclass
class Source:
    """A labelled mesh read from a file."""

    path: str                           # the file read, for messages
    kind: str                           # "OBJ", "glTF", "PLY", "CityJSON"
    vertices: np.ndarray                # (V, 3) float64, as in the file (CityJSON: transform applied)
    parts: dict[str, Part]              # segment name -> faces, in order of first appearance
    warnings: list[str] = field(default_factory=list)

    def part(self, name: str, semantic: str | None = None, kind: str = "segment") -> Part:
        """The part named ``name``, created on first use."""
        if name not in self.parts:
            self.parts[name] = Part(name, semantic, kind=kind)
        return self.parts[name]


@dataclass(frozen=True)
class Triangulated:
    """One segment's triangle mesh: its own vertices (float64, moved) and faces (int32)."""

    name: str
    semantic: str | None
    vertices: np.ndarray
    faces: np.ndarray


def triangulate(source: Source) -> tuple[list[Triangulated], int]:
    """Triangulate every part of ``source``, in the source's coordinates.

    Polygons (with holes) go through mapbox earcut in their own plane (Newell's normal); faces
    with fewer than three distinct vertices, or of zero area, are **dropped** and counted.

    Parameters
    ----------
    source : Source

    Returns
    -------
    list of Triangulated, int
        The parts that keep at least one triangle (each compacted to its own vertices), and the
        number of degenerate faces and polygons dropped.

    Raises
    ------
    SceneError
        When every face of the source is degenerate or the source has none.
    """
    out, dropped = [], 0
    v = source.vertices
    for part in source.parts.values():
        given = [t for t in part.triangles if len(t)]
        faces = np.concatenate(given).astype(np.int64) if given else np.zeros((0, 3), np.int64)
        keep = _non_degenerate(v, faces)
        dropped += int((~keep).sum())
        tris = [faces[keep]]
        for poly in part.polygons:
            t = _earcut_or_refuse(v, poly, source, part)
            if t is None:
                dropped += 1
            else:
                tris.append(t)
        faces = np.concatenate(tris)
        if len(faces) == 0:
            if given or part.polygons:
                raise SceneError(f"{source.path}: {part.kind} '{part.name}': all its "
                                 f"{sum(map(len, given)) + len(part.polygons)} faces are degenerate (fewer than 3 distinct vertices or no area); fix or "
                                 "delete them")
            source.warnings.append(f"{source.path}: {part.kind} '{part.name}' has no faces; it gets no segment")
            continue
        used, inverse = np.unique(faces.ravel(), return_inverse=True)
        out.append(Triangulated(part.name, part.semantic, v[used], inverse.reshape(-1, 3).astype(np.int32)))
    if not out:
        raise SceneError(f"{source.path}: no faces with an area (all {dropped} faces are degenerate, or the "
                         f"{source.kind} holds none); export the surfaces as polygons or triangles")
    return out, dropped


def _non_degenerate(v: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Triangles with three distinct vertices and an area (relative to their size)."""
    if len(faces) == 0:
        return np.zeros(0, bool)
    a, b, c = (v[faces[:, i]] for i in range(3))
    b, c = b - a, c - a                              # relative: exact enough at survey coordinates
    area2 = np.linalg.norm(np.cross(b, c), axis=1)
    size2 = np.maximum((b * b).sum(1), (c * c).sum(1))
    distinct = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    return distinct & (area2 > DEGENERATE_RATIO * size2)


def _earcut_or_refuse(v: np.ndarray, poly: Polygon, source: Source, part: Part) -> np.ndarray | None:
    """:func:`_earcut`, with a self-crossing polygon refused: earcut would drop part of it."""
    try:
        return _earcut(v, poly)
    except _Crossing as exc:
        what = f"{poly.where}: the polygon" if poly.where else "a polygon"
        raise SceneError(f"{source.path}: {part.kind} '{part.name}': {what} crosses itself (its {exc}); reorder "
                         "its vertices or split it into polygons that do not cross themselves") from None


def _earcut(v: np.ndarray, poly: Polygon) -> np.ndarray | None:
    """Triangles (k, 3) of one polygon with holes, or None when it is degenerate; raises
    :class:`_Crossing` when it crosses itself."""
    import mapbox_earcut

    rings = [np.asarray(r, np.int64) for r in poly.rings]
    rings = [r[:-1] if len(r) > 1 and r[0] == r[-1] else r for r in rings]   # closed rings: once
    if len(rings[0]) < 3 or len(np.unique(rings[0])) < 3:
        return None
    idx = np.concatenate(rings)
    sizes = [len(r) for r in rings]
    centred = v[idx] - v[idx].mean(axis=0)           # float64, near 0: survey offsets cancel
    n = _normal(centred[:sizes[0]])
    if n is None:
        _check_cancelling_lobes(centred, sizes)
        return None
    flat = _in_plane(centred, n)
    _check_no_crossing(flat, sizes)
    tri = np.asarray(mapbox_earcut.triangulate_float64(flat, np.cumsum(sizes).astype(np.uint32)))
    if len(tri) == 0:
        return None
    tri = idx[tri.reshape(-1, 3)]
    tri = tri[_non_degenerate(v, tri)]
    if len(tri) == 0:
        return None
    a, b, c = (v[tri[:, i]] for i in range(3))
    back = np.cross(b - a, c - a) @ n < 0            # each triangle wound as the outer ring
    tri[back] = tri[back][:, ::-1]
    return tri


def _normal(outer: np.ndarray) -> np.ndarray | None:
    """The unit normal of a ring (Newell's), or None when its area is too small for its
    perimeter (:data:`DEGENERATE_RATIO`)."""
    normal = np.cross(outer, np.roll(outer, -1, axis=0)).sum(axis=0)     # Newell: 2 x area normal
    area2 = np.linalg.norm(normal)
    perimeter = np.linalg.norm(np.diff(np.vstack([outer, outer[:1]]), axis=0), axis=1).sum()
    return None if area2 <= DEGENERATE_RATIO * perimeter ** 2 else normal / area2


def _in_plane(points: np.ndarray, n: np.ndarray) -> np.ndarray:
    """2D coordinates of ``points`` in the plane of normal ``n``: (u, w, n) right-handed, so that
    earcut keeps the winding."""
    u = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    u /= np.linalg.norm(u)
    return np.stack([points @ u, points @ np.cross(n, u)], 1)


def _check_cancelling_lobes(centred: np.ndarray, sizes: list[int]) -> None:
    """A ring of no net area that still spans a plane may be a bow-tie whose two lobes cancel:
    check it for crossing edges in its best-fit plane (a line has no such plane)."""
    s, vt = np.linalg.svd(centred, full_matrices=False)[1:]
    if s[1] > np.sqrt(DEGENERATE_RATIO) * s[0]:
        _check_no_crossing(_in_plane(centred, vt[-1]), sizes)


class _Crossing(ValueError):
    """Two edges of a polygon cross (the message names them)."""


def _check_no_crossing(xy: np.ndarray, sizes: list[int]) -> None:
    """Raise :class:`_Crossing` when two edges of the rings (``sizes`` points each, one after the
    other in ``xy``) cross at a point inside both. Touching (a shared vertex, a vertex on an
    edge) is not crossing: earcut takes it."""
    start = np.repeat(np.cumsum([0] + sizes[:-1]), sizes)
    size = np.repeat(sizes, sizes)
    a = np.arange(len(xy))
    p, q = xy[a], xy[start + (a - start + 1) % size]
    eps = 1e-12 * max(float(np.ptp(xy, axis=0).max()), 1e-300) ** 2

    def side(o, d, x):                                 # sign of the cross product (d - o) x (x - o)
        c = (d[..., 0] - o[..., 0]) * (x[..., 1] - o[..., 1]) - (d[..., 1] - o[..., 1]) * (x[..., 0] - o[..., 0])
        return np.where(np.abs(c) > eps, np.sign(c), 0.0)

    for i0 in range(0, len(a), 512):                   # row blocks bound the memory of huge rings
        i = slice(i0, i0 + 512)
        P, Q = p[i, None], q[i, None]
        cross = (side(P, Q, p[None]) * side(P, Q, q[None]) < 0) & (side(p[None], q[None], P) * side(p[None], q[None], Q) < 0)
        if cross.any():
            e1, e2 = np.argwhere(cross)[0] + (i0, 0)
            raise _Crossing(_edge_pair(int(e1), int(e2), start, size))


def _edge_pair(e1: int, e2: int, start: np.ndarray, size: np.ndarray) -> str:
    """``edges 1 and 3`` (of the outer ring, numbered from 1), or ``edge 2 and hole 1's edge 4``."""
    ring_starts = list(dict.fromkeys(start.tolist()))
    (r1, k1), (r2, k2) = sorted((ring_starts.index(int(start[e])), int(e - start[e]) + 1) for e in (e1, e2))
    if r1 == r2 == 0:
        return f"edges {k1} and {k2} cross"
    return f"{_edge_name(r1, k1)} and {_edge_name(r2, k2)} cross"


def _edge_name(ring: int, k: int) -> str:
    return f"edge {k}" if ring == 0 else f"hole {ring}'s edge {k}"


def local_origin(parts: list[Triangulated]) -> np.ndarray:
    """The local origin of survey coordinates: ``[0, 0, 0]`` when every coordinate lies within
    :data:`SURVEY_LIMIT` of 0, else the centre of the bounding box in x and y and its bottom in z,
    each rounded to the metre (so that the origin reads as the survey's own numbers)."""
    lo = np.min([p.vertices.min(axis=0) for p in parts], axis=0)
    hi = np.max([p.vertices.max(axis=0) for p in parts], axis=0)
    if max(np.abs(lo).max(), np.abs(hi).max()) <= SURVEY_LIMIT:
        return np.zeros(3)
    return np.round(np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]]))


def origin_text(origin: np.ndarray) -> str:
    """``origin`` as the messages and the provenance show it: ``[652340.000, 6862275.000, 35.000]``."""
    return "[" + ", ".join(f"{x:.3f}" for x in origin) + "]"


def moved(parts: list[Triangulated], origin: np.ndarray) -> list[Triangulated]:
    """``parts`` with ``origin`` subtracted from every vertex (float64)."""
    o = np.asarray(origin, np.float64)
    return [Triangulated(p.name, p.semantic, p.vertices - o, p.faces) for p in parts]
