"""Wavefront OBJ: segments from ``usemtl`` materials (``--group material``, the default) or from
``o``/``g`` objects (``--group object``).

Read: ``v x y z`` (a fourth weight is ignored), ``f`` with 1-based or negative (relative)
indices in any of the forms ``i``, ``i/t``, ``i//n``, ``i/t/n``; faces of more than three
vertices are polygons (triangulated by earcut, not a fan). ``o`` and ``g`` both name the object
of the faces that follow (``g a b``: the object ``a b``). Faces before any ``usemtl`` belong to
the material ``unnamed`` (before any ``o``/``g``: the object ``unnamed``). Texture
coordinates, normals, ``mtllib`` and smoothing groups are ignored. Coordinates are read as
float64. A keyword and its values may be separated by tabs as well as spaces.

Refused, each with its line number: a vertex that is not 3 finite numbers (``v nan 4 8``), a
face index out of range (``f 0 1 2``: OBJ counts from 1), a polygon that crosses itself (a
bow-tie quad; :func:`~framework.convert.model.triangulate`), and a material (``--group
object``: object) name that is not UTF-8 (a Latin-1 ``usemtl b\\xe9ton``: two such names would
otherwise read alike).
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
    vnums: list[int] = []                                     # the line number of each vertex
    faces: dict[str, tuple[list[str], list[int], list[tuple[int, list[int]]]]] = {}  # name -> triangles, lines, polygons
    current = {"material": "unnamed", "object": "unnamed"}
    names: list[tuple[str, str]] = []                         # every material/object named, in order
    for n, line in enumerate(text.splitlines(), start=1):
        head = line[:2]
        key, rest = ("v", line[2:]) if head == "v " else ("f", line[2:]) if head == "f " else _keyword(line)
        if key == "v":
            vlines.append(rest)
            vnums.append(n)
        elif key == "f":
            tris, nums, polys = faces.setdefault(current[kind], ([], [], []))
            body = rest.split("#", 1)[0]
            if "-" in body or len(body.split()) != 3:
                polys.append((n, _indices(body, len(vlines), n, path)))
            else:
                tris.append(body)
                nums.append(n)
        elif key in ("usemtl", "o", "g"):
            which = "material" if key == "usemtl" else "object"
            current[which] = _name(rest, n, path, kind) if which == kind else rest.strip() or "unnamed"
            names.append((which, current[which]))
    vertices = _vertices(vlines, vnums, path)
    source = Source(str(path), "OBJ", vertices, {})
    for name in dict.fromkeys(n for k, n in names if k == kind):
        source.part(name, kind=kind)                          # a named material with no faces: warned
    for name, (tris, nums, polys) in faces.items():
        part = source.part(name, kind=kind)
        if tris:
            part.triangles.append(_triangles(tris, nums, len(vertices), path))
        for n, idx in polys:
            if max(idx) >= len(vertices):
                raise SceneError(f"{path}: line {n}: vertex index {max(idx) + 1} > {len(vertices)} vertices; "
                                 "fix the face")
            if len(idx) == 3:
                part.triangles.append(np.array([idx]))
            else:
                part.polygons.append(Polygon([np.array(idx)], where=f"line {n}"))
    return source


def _keyword(line: str) -> tuple[str, str]:
    """(keyword, the rest) of a line whose keyword is followed by a tab or other whitespace, or
    indented; ("", "") for a blank line."""
    parts = line.split(None, 1)
    return (parts[0], parts[1] if len(parts) > 1 else "") if parts else ("", "")


def _name(rest: str, n: int, path: Path, kind: str) -> str:
    """The ``kind`` (material or object) name of line ``n``; its bytes must be UTF-8 (the file is
    read with undecodable bytes kept apart, so that two Latin-1 names are not merged into one)."""
    name = rest.strip() or "unnamed"
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        raw = name.encode("utf-8", "surrogateescape")
        raise SceneError(f"{path}: line {n}: the {kind} name {raw!r} is not UTF-8; save the OBJ as UTF-8 "
                         f"(e.g. iconv -f latin1 -t utf-8 {Path(path).name} > utf8.obj)") from None
    return name


def _text(path: Path) -> str:
    try:
        return Path(path).read_text(encoding="utf-8", errors="surrogateescape")
    except OSError as exc:
        raise SceneError(f"{path}: cannot read the OBJ ({exc.strerror}); check the path") from None


def _vertices(lines: list[str], nums: list[int], path: Path) -> np.ndarray:
    """The ``v`` lines (read at lines ``nums``) as a (V, 3) float64 array of finite numbers."""
    if not lines:
        raise SceneError(f"{path}: no vertices (an empty OBJ, or not an OBJ); export the mesh with its 'v' lines")
    rows = [line.split() for line in lines]
    try:
        v = np.array([r[:3] for r in rows], dtype=np.float64)
    except ValueError:
        bad = next(i for i, r in enumerate(rows) if len(r) < 3 or not _floats(r[:3]))
        raise SceneError(f"{path}: line {nums[bad]}: vertex {bad + 1} ('v {lines[bad].strip()}') is not 3 numbers; "
                         "fix it") from None
    finite = np.isfinite(v).all(axis=1)
    if not finite.all():
        bad = int(np.argmin(finite))
        raise SceneError(f"{path}: line {nums[bad]}: vertex {bad + 1} ('v {lines[bad].strip()}') has a NaN or "
                         "infinite coordinate; fix it")
    return v


def _floats(values: list[str]) -> bool:
    try:
        [float(v) for v in values]
        return True
    except ValueError:
        return False


def _triangles(lines: list[str], nums: list[int], n_vertices: int, path: Path) -> np.ndarray:
    """The triangle lines ``a b c`` (positive indices, any slash form; read at lines ``nums``) as a
    (k, 3) array, 0-based."""
    try:
        idx = np.array(_SLASHES.sub("", " ".join(lines)).split(), dtype=np.int64).reshape(-1, 3) - 1
    except ValueError:
        bad = next(k for k, line in enumerate(lines) if not _is_indices(_SLASHES.sub("", line).split()))
        raise SceneError(f"{path}: line {nums[bad]}: a face ('f {lines[bad].strip()}') holds something else than "
                         "vertex indices; fix it") from None
    out = (idx < 0) | (idx >= n_vertices)
    if out.any():
        row = int(np.argmax(out.any(axis=1)))
        i = int(idx[row][out[row]][0]) + 1
        raise SceneError(f"{path}: line {nums[row]}: face vertex index {i} out of range (1..{n_vertices}); "
                         + ("OBJ indices start at 1 (negative ones count back from the last vertex); "
                            if i == 0 else "") + "fix the face")
    return idx


def _is_indices(tokens: list[str]) -> bool:
    try:
        [int(t) for t in tokens]
        return True
    except ValueError:
        return False


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
