"""Wavefront OBJ: segments from ``usemtl`` materials (``--group material``, the default) or from
``o``/``g`` objects (``--group object``).

Read: ``v x y z`` (a fourth weight is ignored), ``f`` with 1-based or negative (relative)
indices in any of the forms ``i``, ``i/t``, ``i//n``, ``i/t/n``; faces of more than three
vertices are polygons (triangulated by earcut, not a fan). ``o`` and ``g`` both name the object
of the faces that follow (``g a b``: the object ``a b``). Faces before any ``usemtl`` belong to
the material ``unnamed`` (before any ``o``/``g``: the object ``unnamed``). Texture
coordinates, normals, ``mtllib`` and smoothing groups are ignored. Coordinates are read as
float64.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from framework.convert.model import Polygon, Source
from framework.errors import SceneError

GROUPS = ("material", "object")
_SLASHES = re.compile(r"/\S*")


def read_obj(path: Path, group: str) -> Source:
    """Read ``path`` into a :class:`~framework.convert.model.Source`.

    Parameters
    ----------
    path : Path
        The ``.obj`` file.
    group : str
        ``material`` (``usemtl``) or ``object`` (``o``/``g``).

    Returns
    -------
    Source

    Raises
    ------
    SceneError
        For an unreadable file, a malformed ``v`` or ``f`` line (with its line number), an
        index out of range.
    """
    text = _text(path)
    kind = "material" if group == "material" else "object"
    vlines: list[str] = []
    faces: dict[str, tuple[list[str], list[tuple[int, list[int]]]]] = {}   # name -> (triangle lines, polygons)
    current = {"material": "unnamed", "object": "unnamed"}
    names: list[str] = []                                     # every material/object named, in order
    for n, line in enumerate(text.splitlines(), start=1):
        head = line[:2]
        if head == "v ":
            vlines.append(line[2:])
        elif head == "f ":
            name = current[kind]
            tris, polys = faces.setdefault(name, ([], []))
            body = line[2:].split("#", 1)[0]
            count = len(body.split())
            if "-" in body or count != 3:
                polys.append((n, _indices(body, len(vlines), n, path)))
            else:
                tris.append(body)
        elif line.startswith("usemtl"):
            current["material"] = line[6:].strip() or "unnamed"
            names.append(("material", current["material"]))
        elif head in ("o ", "g ") or line.strip() in ("o", "g"):
            current["object"] = line[1:].strip() or "unnamed"
            names.append(("object", current["object"]))
    vertices = _vertices(vlines, path)
    source = Source(str(path), "OBJ", vertices, {})
    for name in dict.fromkeys(n for k, n in names if k == kind):
        source.part(name, kind=kind)                          # a named material with no faces: warned
    for name, (tris, polys) in faces.items():
        part = source.part(name, kind=kind)
        if tris:
            part.triangles.append(_triangles(tris, len(vertices), path))
        for n, idx in polys:
            if max(idx) >= len(vertices):
                raise SceneError(f"{path}: line {n}: vertex index {max(idx) + 1} > {len(vertices)} vertices; "
                                 "fix the face")
            if len(idx) == 3:
                part.triangles.append(np.array([idx]))
            else:
                part.polygons.append(Polygon([np.array(idx)]))
    return source


def _text(path: Path) -> str:
    try:
        return Path(path).read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise SceneError(f"{path}: cannot read the OBJ ({exc.strerror}); check the path") from None


def _vertices(lines: list[str], path: Path) -> np.ndarray:
    if not lines:
        raise SceneError(f"{path}: no vertices (an empty OBJ, or not an OBJ); export the mesh with its 'v' lines")
    rows = [line.split() for line in lines]
    try:
        return np.array([r[:3] for r in rows], dtype=np.float64)
    except ValueError:
        bad = next(i for i, r in enumerate(rows) if len(r) < 3 or not _floats(r[:3]))
        raise SceneError(f"{path}: vertex {bad + 1} ('v {lines[bad].strip()}') is not 3 numbers; fix it") from None


def _floats(values: list[str]) -> bool:
    try:
        [float(v) for v in values]
        return True
    except ValueError:
        return False


def _triangles(lines: list[str], n_vertices: int, path: Path) -> np.ndarray:
    """The triangle lines ``a b c`` (positive indices, any slash form) as a (k, 3) array, 0-based."""
    try:
        idx = np.array(_SLASHES.sub("", " ".join(lines)).split(), dtype=np.int64).reshape(-1, 3) - 1
    except ValueError:
        raise SceneError(f"{path}: a face ('f' line) holds something else than vertex indices; fix it") from None
    if len(idx) and (idx.min() < 0 or idx.max() >= n_vertices):
        raise SceneError(f"{path}: face vertex index {int(idx.max()) + 1} out of range (1..{n_vertices}); "
                         "fix the faces")
    return idx


def _indices(body: str, seen: int, n: int, path: Path) -> list[int]:
    """0-based vertex indices of one face line (``seen``: vertices defined before it, for
    negative indices)."""
    out = []
    for token in body.split():
        try:
            i = int(token.split("/", 1)[0])
        except ValueError:
            raise SceneError(f"{path}: line {n}: face item '{token}' is not a vertex index; fix the face") from None
        if i == 0 or -i > seen:
            raise SceneError(f"{path}: line {n}: vertex index {i} out of range; fix the face")
        out.append(i - 1 if i > 0 else seen + i)
    return out
