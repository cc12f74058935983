"""CityJSON 1.1 and 2.0: segments from CityObjects and their semantic surfaces.

``--group semantic`` (the default) gives one segment per CityObject and surface type, named
``<object id>/<SurfaceType>`` (``b1/WallSurface``, ``b1/Window``, ``road/TrafficArea``); surfaces
without semantics are ``<object id>/unclassified``. ``--group object`` gives one segment per
CityObject; ``--group material`` one per appearance material (the first theme of
``appearance``; an error when the file has none).

Read: ``transform`` (required: the integer vertices times ``scale`` plus ``translate``, in
float64), the geometry types ``MultiSurface``, ``CompositeSurface``, ``Solid``, ``MultiSolid`` and
``CompositeSolid`` (points and lines are ignored). Each surface is a polygon with holes (its
first ring the outer boundary, the others holes), triangulated by earcut. An object with several
geometries is read at its **highest LoD** only (an LoD2 and an LoD3 of one building would overlap).
Refused, each with one line: an unknown ``version`` (or one written as a JSON number, ``2.0``
for ``"2.0"``), a missing ``transform``, geometry templates (``GeometryInstance``: dereference
them into plain geometry first, or export without templates), a ``type`` other than
``CityJSON``, a CityObject id given twice (JSON would keep the last object only), a semantic or
material value that is not an index of the geometry's list (a negative one included: Python
would read it from the end), and a surface that crosses itself.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from framework.convert.model import Polygon, Source
from framework.errors import SceneError

VERSIONS = ("1.1", "2.0")
GROUPS = ("semantic", "object", "material")
SURFACE_TYPES = ("MultiSurface", "CompositeSurface")
SOLID_TYPES = ("Solid",)
MULTI_SOLID_TYPES = ("MultiSolid", "CompositeSolid")
UNCLASSIFIED = "unclassified"


def read_cityjson(path: Path, group: str) -> tuple[Source, dict]:
    """Read ``path`` into a :class:`~framework.convert.model.Source`.

    Parameters
    ----------
    path : Path
        A CityJSON file (``.city.json`` or ``.json``).
    group : str
        ``semantic``, ``object`` or ``material``.

    Returns
    -------
    Source, dict
        The parts, and facts for the provenance record: ``version``, ``referenceSystem``
        (or None), ``objects`` (the CityObjects read).

    Raises
    ------
    SceneError
        For an unreadable file, invalid JSON, an unknown version, no transform, templates.
    """
    doc = _document(path)
    scale, translate = _transform(doc, path)
    try:
        vertices = np.asarray(doc.get("vertices", []), dtype=np.float64).reshape(-1, 3)
    except ValueError:
        raise SceneError(f"{path}: 'vertices' must be a list of [x, y, z] integer triples; fix the file") from None
    vertices = vertices * scale + translate
    objects = doc.get("CityObjects")
    if not isinstance(objects, dict) or not objects:
        raise SceneError(f"{path}: no CityObjects; the file holds no city model")
    materials = _material_names(doc, path) if group == "material" else None
    source = Source(str(path), "CityJSON", vertices, {})
    n_vertices = len(vertices)
    for oid, obj in objects.items():
        geometries = [g for g in (obj.get("geometry") or []) if isinstance(g, dict)]
        templates = [g for g in geometries if g.get("type") == "GeometryInstance"]
        if templates:
            raise SceneError(f"{path}: CityObject '{oid}' uses a geometry template (GeometryInstance); templates "
                             "are not supported: dereference them into plain geometry first, or export the "
                             "model without templates")
        surfaces = [g for g in geometries if g.get("type") in SURFACE_TYPES + SOLID_TYPES + MULTI_SOLID_TYPES]
        if not surfaces:
            continue
        best = max(surfaces, key=lambda g: _lod(g.get("lod")))
        for poly, semantic, material in _surfaces(best, path, oid):
            if group == "semantic":
                name, sem, kind = f"{oid}/{semantic or UNCLASSIFIED}", semantic, "surface"
            elif group == "object":
                name, sem, kind = oid, None, "CityObject"
            else:
                if material is None:
                    raise SceneError(f"{path}: CityObject '{oid}' has a surface without a material of theme "
                                     f"'{materials[0]}'; use --group semantic or object")
                index = _index(material, len(materials[1]), "material", "appearance materials", f"{path}: {poly.where}")
                name, sem, kind = materials[1][index], None, "material"
            if max(int(r.max()) for r in poly.rings if len(r)) >= n_vertices or min(
                    int(r.min()) for r in poly.rings if len(r)) < 0:
                raise SceneError(f"{path}: CityObject '{oid}': a vertex index is out of range "
                                 f"(0..{n_vertices - 1}); fix the boundaries")
            source.part(name, sem, kind).polygons.append(poly)
    if not source.parts:
        raise SceneError(f"{path}: no surfaces (no CityObject has a MultiSurface, CompositeSurface or Solid "
                         "geometry); nothing to convert")
    facts = {"version": doc["version"], "referenceSystem": (doc.get("metadata") or {}).get("referenceSystem"),
             "objects": sum(1 for o in objects.values() if o.get("geometry"))}
    return source, facts


def _document(path: Path) -> dict:
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise SceneError(f"{path}: cannot read the CityJSON ({exc.strerror}); check the path") from None
    except UnicodeDecodeError:
        raise SceneError(f"{path}: is not UTF-8 text, so not CityJSON; check the file") from None
    if not text.strip():
        raise SceneError(f"{path}: is empty; export the city model again")
    repeated: list[tuple[dict, list[str]]] = []         # JSON objects with a key given twice, and those keys
    try:
        doc = json.loads(text, object_pairs_hook=lambda pairs: _keep_repeats(pairs, repeated))
    except json.JSONDecodeError as exc:
        raise SceneError(f"{path}: is not valid JSON (line {exc.lineno}: {exc.msg}); fix the file") from None
    if not isinstance(doc, dict) or doc.get("type") != "CityJSON":
        raise SceneError(f"{path}: is not CityJSON ('type' must be 'CityJSON'); check the file")
    twice = next((keys[0] for d, keys in repeated if d is doc.get("CityObjects")), None)
    if twice is not None:
        raise SceneError(f"{path}: CityObject id '{twice}' appears twice in CityObjects (JSON keeps the last, so "
                         "the first would be lost); give each object its own id")
    version = doc.get("version")
    if isinstance(version, (int, float)) and not isinstance(version, bool):
        raise SceneError(f"{path}: 'version' is the number {version}; CityJSON writes it as a string: "
                         f"\"version\": \"{version}\" (the converter reads {' and '.join(VERSIONS)})")
    if version not in VERSIONS:
        raise SceneError(f"{path}: CityJSON version {version!r} is not supported; the converter reads "
                         f"{' and '.join(VERSIONS)} (upgrade the file, e.g. with cjio upgrade)")
    return doc


def _keep_repeats(pairs: list[tuple[str, object]], repeated: list) -> dict:
    """``dict(pairs)``, noting in ``repeated`` the dict and its keys given more than once."""
    out = dict(pairs)
    if len(out) != len(pairs):
        seen: set = set()
        repeated.append((out, [k for k, _ in pairs if k in seen or seen.add(k)]))
    return out


def _transform(doc: dict, path: Path) -> tuple[np.ndarray, np.ndarray]:
    t = doc.get("transform")
    if not isinstance(t, dict):
        raise SceneError(f"{path}: no 'transform'; CityJSON {doc['version']} stores integer vertices with a "
                         "transform {scale, translate}: add it (cjio ... save compresses the file)")
    try:
        scale = np.asarray(t["scale"], np.float64)
        translate = np.asarray(t["translate"], np.float64)
    except (KeyError, TypeError, ValueError):
        raise SceneError(f"{path}: 'transform' must hold 'scale' and 'translate', 3 numbers each; fix it") from None
    if scale.shape != (3,) or translate.shape != (3,) or not np.isfinite([*scale, *translate]).all() or (scale <= 0).any():
        raise SceneError(f"{path}: 'transform' must hold 'scale' (3 numbers > 0) and 'translate' (3 numbers); fix it")
    return scale, translate


def _lod(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return -1.0


def _material_names(doc: dict, path: Path) -> tuple[str, list[str]]:
    app = doc.get("appearance") or {}
    mats = app.get("materials") or []
    if not mats:
        raise SceneError(f"{path}: no appearance materials; use --group semantic (surface types) or object")
    names = [str(m.get("name") or f"material{i}") for i, m in enumerate(mats)]
    themes = [t for o in doc["CityObjects"].values() for g in (o.get("geometry") or [])
              for t in (g.get("material") or {})]
    return (themes[0] if themes else "", names)


def _surfaces(geom: dict, path: Path, oid: str):
    """(polygon, semantic type or None, material index or None) of every surface of ``geom``."""
    t = geom["type"]
    depth = 1 if t in SURFACE_TYPES else 2 if t in SOLID_TYPES else 3
    sem = geom.get("semantics") or {}
    types = [s.get("type") for s in (sem.get("surfaces") or [])]
    mat = next(iter((geom.get("material") or {}).values()), None)
    try:
        for poly, path_idx in _walk(geom["boundaries"], depth, ()):
            where = f"surface {list(path_idx)}"
            s = _index(_at(sem.get("values"), path_idx), len(types), "semantic", "semantic surfaces",
                       f"{path}: CityObject '{oid}': {where}")
            m = mat.get("value") if mat is not None and "value" in mat else _at(
                mat.get("values") if mat else None, path_idx)
            rings = [np.asarray(r, np.int64) for r in poly]
            yield Polygon(rings, where=f"CityObject '{oid}': {where}"), (types[s] if s is not None else None), m
    except (TypeError, KeyError, IndexError, ValueError):
        raise SceneError(f"{path}: CityObject '{oid}': malformed {t} boundaries or semantics; validate the "
                         "file (cjval)") from None


def _index(value, count: int, what: str, noun: str, where: str) -> int | None:
    """``value``, a semantic or material index of a surface, checked: null, or 0..count-1 (a
    negative one would pick a surface from the end, as Python indexing does)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < count:
        raise SceneError(f"{where} has the {what} value {json.dumps(value)}, not an index of its {count} {noun} "
                         f"(0..{count - 1}) or null; fix it (cjval validates the file)")
    return value


def _walk(node, depth: int, where: tuple):
    """The surfaces (lists of rings) of a boundary array nested ``depth`` levels above surfaces."""
    if depth == 0:
        yield node, where
        return
    for i, child in enumerate(node):
        yield from _walk(child, depth - 1, where + (i,))


def _at(values, where: tuple):
    """The semantic/material value of the surface at ``where`` (None where not given)."""
    for i in where:
        if values is None:
            return None
        values = values[i]
    return values
