"""PLY with a per-face integer label: one segment per label.

The face element carries an integer property beside its vertex list: the one named ``label``,
or else the only integer (non-list) property of ``face``. The names of the labels come from a
**YAML file beside the mesh**, ``<stem>.labels.yaml`` (``street.ply`` → ``street.labels.yaml``),
mapping each label to a segment name::

    0: asphalt
    1: facade
    2: window

A face whose label the table does not name is an error; a name no face uses is a warning (it
gets no segment). Read with trimesh (ASCII and binary); vertex coordinates keep the file's
precision (store survey coordinates as ``double``); faces of more than three vertices are
polygons (earcut).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from framework.convert.model import Polygon, Source
from framework.errors import SceneError

LABEL = "label"


def labels_file(path: Path) -> Path:
    """The label table of the PLY ``path``: ``<stem>.labels.yaml`` beside it."""
    return Path(path).with_name(Path(path).stem + ".labels.yaml")


def read_ply(path: Path) -> Source:
    """Read ``path`` and its label table into a :class:`~framework.convert.model.Source`.

    Parameters
    ----------
    path : Path
        The ``.ply`` file.

    Returns
    -------
    Source
        One part per label, named by the table; ``warnings`` lists the table's unused labels.

    Raises
    ------
    SceneError
        For an unreadable file, no label property, a missing or malformed table, a face label
        the table does not name.
    """
    faces, labels, vertices = _read(path)
    table = _table(path)
    source = Source(str(path), "PLY", vertices, {})
    unknown = sorted(set(np.unique(labels).tolist()) - set(table))
    if unknown:
        raise SceneError(f"{labels_file(path)}: face label {unknown[0]} of {path} has no name "
                         f"(labels named: {', '.join(map(str, sorted(table)))}); add '{unknown[0]}: <segment name>'")
    used = set(np.unique(labels).tolist())
    for label, name in table.items():
        if label not in used:
            source.warnings.append(f"{labels_file(path)}: label {label} ({name}) is used by no face of {path}; "
                                   "it gets no segment")
            continue
        part = source.part(name, kind="label")
        mask = labels == label
        if isinstance(faces, np.ndarray) and faces.ndim == 2:
            part.triangles.append(faces[mask][:, :3] if faces.shape[1] == 3 else np.zeros((0, 3), int))
            if faces.shape[1] > 3:
                part.polygons += [Polygon([faces[i]], where=f"face {i}") for i in np.flatnonzero(mask)]
        else:
            for i in np.flatnonzero(mask):
                f = np.asarray(faces[i], np.int64)
                if len(f) == 3:
                    part.triangles.append(f[None])
                else:
                    part.polygons.append(Polygon([f], where=f"face {i}"))
    return source


def _read(path: Path):
    """(faces: (F, k) array or object array of index arrays, labels (F,), vertices (V, 3) float64)."""
    import trimesh

    if not Path(path).is_file():
        raise SceneError(f"{path}: no such file; check the path")
    try:
        mesh = trimesh.load(str(path), file_type="ply", process=False, force="mesh")
        raw = mesh.metadata["_ply_raw"]
    except Exception as exc:  # trimesh raises many kinds on a bad header or truncated data
        raise SceneError(f"{path}: cannot read the PLY ({str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__}); "
                         "re-export it") from None
    face = _columns(raw["face"]["data"]) if "face" in raw else {}
    lists = [k for k in ("vertex_indices", "vertex_index") if k in face]
    if not lists or len(face[lists[0]]) == 0:
        raise SceneError(f"{path}: no faces (an empty PLY, or a point cloud); export a mesh with faces")
    ints = [k for k, a in face.items() if k not in lists and np.asarray(a).dtype.kind in "iu"
            and (np.asarray(a).ndim == 1 or np.asarray(a).shape[1:] == (1,))]
    key = LABEL if LABEL in ints else (ints[0] if len(ints) == 1 else None)
    if key is None:
        what = f"several ({', '.join(ints)})" if ints else "none"
        raise SceneError(f"{path}: the face element needs one integer label property (found {what}); name it "
                         f"'{LABEL}' (property int {LABEL})")
    v = _columns(raw["vertex"]["data"])
    vertices = np.stack([np.asarray(v[c], np.float64).ravel() for c in "xyz"], axis=1)
    faces = face[lists[0]]
    if isinstance(faces, np.ndarray) and faces.dtype.names:    # binary, one list length: (count, indices)
        faces = faces[faces.dtype.names[-1]]
    faces = np.asarray(faces) if not (isinstance(faces, np.ndarray) and faces.dtype == object) else faces
    flat = np.concatenate([np.asarray(f).ravel() for f in faces]) if faces.dtype == object else faces.ravel()
    if len(flat) and (flat.min() < 0 or flat.max() >= len(vertices)):
        raise SceneError(f"{path}: face indices out of range (0..{len(vertices) - 1}); re-export the mesh")
    if not np.isfinite(vertices).all():
        raise SceneError(f"{path}: vertices with NaN/Inf coordinates; clean the mesh")
    return faces, np.asarray(face[key], np.int64).ravel(), vertices


def _columns(data) -> dict:
    """trimesh's element data (a dict of arrays for ASCII, a structured array for binary) as a dict."""
    if isinstance(data, np.ndarray) and data.dtype.names:
        return {name: data[name] for name in data.dtype.names}
    return dict(data)


def _table(path: Path) -> dict[int, str]:
    table_path = labels_file(path)
    if not table_path.is_file():
        raise SceneError(f"{table_path}: missing; a labelled PLY needs its label table beside it "
                         "(one line per label: '0: asphalt')")
    try:
        table = yaml.safe_load(table_path.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError):
        raise SceneError(f"{table_path}: is not valid YAML; write one line per label: '0: asphalt'") from None
    if not isinstance(table, dict) or not table or not all(
            isinstance(k, int) and not isinstance(k, bool) and isinstance(n, str) and n.strip()
            for k, n in table.items()):
        raise SceneError(f"{table_path}: must map integer labels to segment names, one line per label: "
                         "'0: asphalt'")
    names = list(table.values())
    twice = next((n for i, n in enumerate(names) if n in names[:i]), None)
    if twice is not None:
        raise SceneError(f"{table_path}: the name '{twice}' is given to two labels; a segment name names one label")
    return dict(table)
