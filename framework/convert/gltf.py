"""glTF 2.0 (``.gltf`` with its buffers, or ``.glb``), read with trimesh: segments from
materials (``--group material``, the default) or from nodes (``--group object``).

Every node's mesh is placed by its world transform (float64). glTF is **+y up**; the world of a
scene folder is +z up, so a point (x, y, z) of the file becomes (x, −z, y) (the inverse of what
exporters do to a +z-up model). A primitive without a material belongs to the material
``unnamed``; a node without a name is named after its mesh. Points and lines are ignored.

Positions are float32 in every glTF: beyond 1 km of 0 (survey coordinates) a mesh gets a warning
with their spacing there (0.5 m at 6.9e6 m); a survey offset in a node's translation (float64
JSON) over local positions is exact.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from framework.convert.model import SURVEY_LIMIT, Source
from framework.errors import SceneError

GROUPS = ("material", "object")
#: glTF (+y up) to the scene's world (+z up): (x, y, z) -> (x, -z, y)
Y_UP_TO_Z_UP = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])


def read_gltf(path: Path, group: str) -> Source:
    """Read ``path`` into a :class:`~framework.convert.model.Source`.

    Parameters
    ----------
    path : Path
        A ``.gltf`` or ``.glb`` file.
    group : str
        ``material`` or ``object`` (node).

    Returns
    -------
    Source

    Raises
    ------
    SceneError
        For an unreadable file or one without triangles.
    """
    import trimesh

    if not Path(path).is_file():
        raise SceneError(f"{path}: no such file; check the path")
    try:
        scene = trimesh.load(str(path), force="scene", process=False)
    except Exception as exc:  # trimesh raises many kinds on a bad file
        text = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise SceneError(f"{path}: cannot read the glTF ({text}); re-export it") from None
    chunks, parts, far = [], [], {}
    n = 0
    for node in scene.graph.nodes_geometry:
        transform, geom_name = scene.graph[node]
        mesh = scene.geometry[geom_name]
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            continue
        v = np.asarray(mesh.vertices, np.float64)
        far[geom_name] = float(np.abs(v).max())
        v = (v @ np.asarray(transform, np.float64)[:3, :3].T + np.asarray(transform, np.float64)[:3, 3])
        chunks.append(v @ Y_UP_TO_Z_UP.T)
        material = getattr(getattr(mesh.visual, "material", None), "name", None) or "unnamed"
        name = material if group == "material" else (str(node) or geom_name)
        parts.append((name, np.asarray(mesh.faces, np.int64) + n))
        n += len(v)
    if not chunks:
        raise SceneError(f"{path}: no triangles (an empty glTF, or only points and lines); export a mesh")
    source = Source(str(path), "glTF", np.concatenate(chunks), {}, warnings=_float32_warning(path, far))
    for name, faces in parts:
        source.part(name, kind="material" if group == "material" else "node").triangles.append(faces)
    return source


def _float32_warning(path: Path, far: dict[str, float]) -> list[str]:
    """One warning when the positions of some mesh (float32 in every glTF; ``far``: mesh -> its
    largest coordinate) lie beyond :data:`~framework.convert.model.SURVEY_LIMIT`: float32 is then
    coarse (0.5 m apart at 6.9e6 m). Node transforms are float64 JSON numbers: a survey offset
    belongs there."""
    beyond = {name: x for name, x in far.items() if x > SURVEY_LIMIT}
    if not beyond:
        return []
    step = float(np.spacing(np.float32(max(beyond.values()))))
    names = ", ".join(f"'{n}'" for n in list(beyond)[:3]) + (f" and {len(beyond) - 3} more" if len(beyond) > 3 else "")
    return [f"{path}: mesh{'es' if len(beyond) > 1 else ''} {names}: float32 positions at {max(beyond.values()):.2g} m "
            f"are {step:g} m apart (errors up to {step / 2:g} m); put the survey offset in a node translation over "
            "local positions, or export OBJ, PLY (double) or CityJSON"]
