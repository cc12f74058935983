"""The scene loader (``docs/scene-format.md``).

:func:`load_scene` reads a scene folder — ``scene.yaml``, Open3D meshes, a COLMAP model
(pycolmap), EXR images and environment maps — checks everything a user can get wrong, and
returns an immutable :class:`~framework.scene.model.Scene`. Every problem raises
:class:`~framework.errors.SceneError` with one line naming the file and the fix; nothing in the
folder is ever written.
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np
import yaml

from framework import kernels as kernel_registry
from framework.errors import SceneError
from framework.scene.exr import read_exr_checked
from framework.scene.model import CHANNELS, Camera, Emitter, Mesh, Scene, Segment

EMITTER_TYPES = ("envmap", "constant", "directional", "area")
PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")


# ----------------------------------------------------------------------------------------------
# Loading
# ----------------------------------------------------------------------------------------------

def load_scene(directory: str | os.PathLike) -> Scene:
    """Load and check a scene folder (``docs/scene-format.md``).

    Parameters
    ----------
    directory : path-like
        Folder holding ``scene.yaml``, ``meshes/``, ``sparse/`` and optionally ``images/``.

    Returns
    -------
    Scene

    Raises
    ------
    SceneError
        With one line naming the offending file and the fix.
    """
    root = Path(directory).expanduser().resolve()
    desc = _read_yaml(root)
    channels = _channels(desc, root)
    segments = tuple(_segment(s, i, root, channels) for i, s in enumerate(_list(desc, "segments", root)))
    if not segments:
        raise SceneError(f"{root / 'scene.yaml'}: 'segments' is empty; list at least one segment")
    emitters, area = _emitters(desc, root, channels)
    meshes = _meshes(root, segments, area)
    cameras = _cameras(root)
    images = _images(root, cameras, channels)
    if images is None and not all(s.reference is not None and set(s.reference) == set(s.kernels)
                                  for s in segments):
        raise SceneError(f"{root}: no images/ folder and not every segment has a reference for each "
                         "kernel; add images/<view>.exr or references to scene.yaml")
    return Scene(name=str(desc.get("name") or root.name), root=root, channels=channels,
                 segments=segments, meshes=meshes, emitters=emitters, cameras=cameras,
                 images=images, content_hash=_content_hash(root))


def _read_yaml(root: Path) -> dict:
    path = root / "scene.yaml"
    if not root.is_dir():
        raise SceneError(f"{root}: scene directory does not exist; pass scene.dir=<folder with scene.yaml>")
    if not path.is_file():
        raise SceneError(f"{path}: missing; a scene folder needs scene.yaml (docs/scene-format.md)")
    try:
        desc = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        line = getattr(getattr(exc, "problem_mark", None), "line", None)
        where = f" line {line + 1}" if line is not None else ""
        raise SceneError(f"{path}:{where} is not valid YAML; fix the syntax") from None
    if not isinstance(desc, dict):
        raise SceneError(f"{path}: must be a mapping with keys name, channels, segments, emitters")
    return desc


def _list(desc: dict, key: str, root: Path) -> list:
    value = desc.get(key)
    if not isinstance(value, list):
        raise SceneError(f"{root / 'scene.yaml'}: '{key}' must be a list")
    return value


def _channels(desc: dict, root: Path) -> tuple[str, ...]:
    name = desc.get("channels", "rgb")
    if name not in CHANNELS:
        raise SceneError(f"{root / 'scene.yaml'}: channels '{name}' unknown; use rgb or mono")
    return CHANNELS[name]


def _values(value, channels, *, what: str, root: Path, unit: bool = False) -> np.ndarray:
    """One number or one per channel, as a (C,) array; ``unit`` demands [0, 1]."""
    where = f"{root / 'scene.yaml'}: {what}"
    try:
        v = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise SceneError(f"{where} must be a number or a list of {len(channels)} numbers") from None
    if v.ndim == 0:
        v = np.full(len(channels), float(v))
    if v.shape != (len(channels),):
        raise SceneError(f"{where} has {v.size} values; give one number or {len(channels)} "
                         f"(one per channel {','.join(channels)})")
    if not np.all(np.isfinite(v)) or (unit and (v.min() < 0 or v.max() > 1)):
        raise SceneError(f"{where} = {v.tolist()} is outside [0, 1]; reflectances lie in [0, 1]"
                         if unit else f"{where} must be finite")
    return v


def _segment(s, i: int, root: Path, channels) -> Segment:
    where = f"{root / 'scene.yaml'}: segment {i}"
    if not isinstance(s, dict) or not s.get("name"):
        raise SceneError(f"{where} needs a name")
    name = str(s["name"])
    meshes = s.get("meshes") or []
    if not meshes:
        raise SceneError(f"{root / 'scene.yaml'}: segment '{name}' has no meshes; list its PLY files")
    ks = s.get("kernels") or ["diffuse"]
    for k in ks:
        kernel_registry.get(k)
    if len(set(ks)) != len(ks):
        raise SceneError(f"{root / 'scene.yaml'}: segment '{name}' lists a kernel twice: {ks}")
    ref = s.get("reference")
    if ref is not None:
        if not isinstance(ref, dict) or not set(ref) <= set(ks):
            raise SceneError(f"{root / 'scene.yaml'}: segment '{name}' reference must map its kernels "
                             f"{ks} to values")
        ref = {k: _values(v, channels, what=f"segment '{name}' reference {k}", root=root, unit=True)
               for k, v in ref.items()}
    return Segment(name, tuple(str(m) for m in meshes), tuple(ks), ref)


def _emitters(desc: dict, root: Path, channels):
    emitters, area = [], {}
    for i, e in enumerate(desc.get("emitters") or []):
        t = e.get("type") if isinstance(e, dict) else None
        if t not in EMITTER_TYPES:
            raise SceneError(f"{root / 'scene.yaml'}: emitter {i} type '{t}' unknown; use one of "
                             f"{', '.join(EMITTER_TYPES)}")
        val = lambda key: _values(e.get(key), channels, what=f"emitter {i} ({t}) {key}", root=root)
        if t == "constant":
            emitters.append(Emitter(t, radiance=val("radiance")))
        elif t == "directional":
            d = np.asarray(e.get("direction"), dtype=float)
            if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) == 0:
                raise SceneError(f"{root / 'scene.yaml'}: emitter {i} direction must be 3 finite numbers")
            emitters.append(Emitter(t, direction=d / np.linalg.norm(d), irradiance=val("irradiance")))
        elif t == "envmap":
            image = read_exr_checked(root / str(e.get("file")), channels=channels)
            emitters.append(Emitter(t, image=image, scale=float(e.get("scale", 1.0)), file=str(e.get("file"))))
        else:
            for m in e.get("meshes") or []:
                area[str(m)] = val("radiance")
            emitters.append(Emitter(t, radiance=val("radiance")))
    if not emitters:
        raise SceneError(f"{root / 'scene.yaml'}: no emitters; the illumination must be known")
    return tuple(emitters), area


def _meshes(root: Path, segments, area: dict) -> tuple[Mesh, ...]:
    owner: dict[str, int] = {}
    for s, seg in enumerate(segments):
        for m in seg.meshes:
            if m in owner:
                raise SceneError(f"{root / 'scene.yaml'}: mesh {m} is in segments "
                                 f"'{segments[owner[m]].name}' and '{seg.name}'; a mesh belongs to one")
            owner[m] = s
    paths = list(owner) + [m for m in area if m not in owner]
    return tuple(Mesh(m, *_read_mesh(root / m), segment=owner.get(m), radiance=area.get(m)) for m in paths)


def _read_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    if not path.is_file():
        raise SceneError(f"{path}: mesh file missing; fix the path in scene.yaml")
    import open3d as o3d
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    mesh = o3d.io.read_triangle_mesh(str(path))
    v = np.asarray(mesh.vertices, dtype=float)
    f = np.asarray(mesh.triangles, dtype=np.int64)
    if len(f) == 0:
        raise SceneError(f"{path}: no triangles (unreadable or empty PLY); export a triangle mesh")
    if not np.isfinite(v).all():
        raise SceneError(f"{path}: vertices with NaN/Inf coordinates; clean the mesh")
    if f.min() < 0 or f.max() >= len(v):
        raise SceneError(f"{path}: face indices out of range; re-export the mesh")
    return v, f.astype(np.int32)


def _cameras(root: Path) -> tuple[Camera, ...]:
    sparse = root / "sparse"
    if not any((sparse / f).is_file() for f in ("cameras.txt", "cameras.bin")):
        raise SceneError(f"{sparse}: missing COLMAP model; add cameras/images/points3D (.txt or .bin)")
    import pycolmap
    try:
        rec = pycolmap.Reconstruction(str(sparse))
    except Exception as exc:  # pycolmap raises plain RuntimeError/ValueError with long text
        raise SceneError(f"{sparse}: unreadable COLMAP model ({str(exc).splitlines()[0][:120]}); "
                         "re-export it with COLMAP") from None
    cams = []
    for image in rec.images.values():
        c = rec.cameras[image.camera_id]
        model = c.model.name
        if model not in PINHOLE_MODELS:
            raise SceneError(f"{sparse}: camera {image.camera_id} of image {image.name} is {model}; "
                             "undistort the images to a PINHOLE camera (colmap image_undistorter)")
        fx, fy = c.focal_length_x, c.focal_length_y
        if abs(fx - fy) > 1e-6 * fx:
            raise SceneError(f"{sparse}: camera {image.camera_id} of image {image.name} has fx={fx} != "
                             f"fy={fy}; resample the images to square pixels")
        T = np.asarray(image.cam_from_world().matrix(), dtype=float)
        cams.append(Camera(image.name, int(c.width), int(c.height), float(fx),
                           float(c.principal_point_x), float(c.principal_point_y), T))
    if not cams:
        raise SceneError(f"{sparse}: the COLMAP model has no images; register at least one")
    return tuple(sorted(cams, key=lambda c: c.name))


def image_file(root: Path, camera_name: str) -> Path:
    """``images/street_003.exr`` for the COLMAP image ``street_003.png``."""
    return root / "images" / (Path(camera_name).stem + ".exr")


def _images(root: Path, cameras, channels) -> dict[str, np.ndarray] | None:
    if not (root / "images").is_dir():
        return None
    return {c.name: read_exr_checked(image_file(root, c.name), channels=channels,
                                     size=(c.height, c.width)) for c in cameras}


def _content_hash(root: Path) -> str:
    """SHA-256 over every file of the scene (names and bytes): the key of every cache entry."""
    h = hashlib.sha256()
    for p in sorted(q for q in root.rglob("*") if q.is_file() and q.name != "preview.png"):
        h.update(str(p.relative_to(root)).encode())
        h.update(hashlib.sha256(p.read_bytes()).digest())
    return h.hexdigest()[:16]
