"""Small triangle-mesh primitives (numpy): quads, boxes, icospheres, and a merge.

A mesh is a tuple ``(vertices (n, 3) float, faces (m, 3) int)``; faces are counter-clockwise
around their outward normal.
"""
from __future__ import annotations

import numpy as np

Mesh = tuple[np.ndarray, np.ndarray]


def quad(origin, edge_u, edge_v) -> Mesh:
    """Parallelogram ``origin + s·edge_u + t·edge_v`` (s, t in [0, 1]); normal = edge_u × edge_v."""
    o, u, v = (np.asarray(a, float) for a in (origin, edge_u, edge_v))
    verts = np.array([o, o + u, o + u + v, o + v])
    return verts, np.array([[0, 1, 2], [0, 2, 3]])


def box(origin, ex, ey, ez) -> Mesh:
    """Closed parallelepiped spanned by ``ex, ey, ez`` at ``origin`` (right-handed), normals outward."""
    o, ex, ey, ez = (np.asarray(a, float) for a in (origin, ex, ey, ez))
    if np.dot(np.cross(ex, ey), ez) < 0:
        ex, ey = ey, ex
    faces = [quad(o, ey, ex), quad(o + ez, ex, ey),            # bottom (-ez), top (+ez)
             quad(o, ex, ez), quad(o + ey, ez, ex),            # -ey side, +ey side
             quad(o, ez, ey), quad(o + ex, ey, ez)]            # -ex side, +ex side
    return merge(faces)


def aabox(lo, hi) -> Mesh:
    """Axis-aligned closed box between corners ``lo`` and ``hi``."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    d = hi - lo
    return box(lo, [d[0], 0, 0], [0, d[1], 0], [0, 0, d[2]])


def merge(meshes: list[Mesh]) -> Mesh:
    """Concatenate meshes into one (indices offset)."""
    verts, faces, n = [], [], 0
    for v, f in meshes:
        verts.append(np.asarray(v, float))
        faces.append(np.asarray(f, int) + n)
        n += len(v)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), int)
    return np.concatenate(verts), np.concatenate(faces)


def flip(mesh: Mesh) -> Mesh:
    """The same surface with reversed winding (normals flipped)."""
    v, f = mesh
    return v, f[:, ::-1].copy()


def icosphere(subdivisions: int = 2, radius: float = 1.0) -> Mesh:
    """Icosphere of ``20·4^subdivisions`` triangles, vertices on the sphere, normals outward."""
    t = (1 + 5 ** 0.5) / 2
    v = [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
         [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]
    f = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
         [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
         [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    verts = [np.array(p, float) / np.linalg.norm(p) for p in v]
    faces = f
    for _ in range(subdivisions):
        verts, faces = _subdivide(verts, faces)
    return np.array(verts) * radius, np.array(faces, int)


def _subdivide(verts: list, faces: list) -> tuple[list, list]:
    """Split each triangle in four, projecting the new midpoints onto the unit sphere."""
    cache: dict[tuple[int, int], int] = {}

    def mid(a: int, b: int) -> int:
        key = (min(a, b), max(a, b))
        if key not in cache:
            m = verts[a] + verts[b]
            verts.append(m / np.linalg.norm(m))
            cache[key] = len(verts) - 1
        return cache[key]

    out = []
    for a, b, c in faces:
        ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
        out += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
    return verts, out


def face_normals(mesh: Mesh) -> np.ndarray:
    """Unit normals (m, 3) of the triangles from their winding."""
    v, f = mesh
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def compact(mesh: Mesh) -> Mesh:
    """Drop the vertices no face uses (re-indexing the faces)."""
    v, f = mesh
    used, inverse = np.unique(f.ravel(), return_inverse=True)
    return v[used], inverse.reshape(f.shape)


def orient_towards(mesh: Mesh, point) -> Mesh:
    """Flip each triangle whose normal points away from ``point`` (e.g. recess sides inwards)."""
    v, f = mesh
    centres = v[f].mean(axis=1)
    away = np.einsum("ij,ij->i", face_normals(mesh), np.asarray(point, float) - centres) < 0
    f = f.copy()
    f[away] = f[away][:, ::-1]
    return v, f
