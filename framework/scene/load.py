"""The scene loader (``docs/scene-format.md``).

:func:`load_scene` reads a scene folder and returns an immutable
:class:`~framework.scene.model.Scene`. It checks ``scene.yaml`` completely first
(:mod:`framework.scene.schema`), before it opens anything heavy; then it reads the Open3D
meshes, the environment maps, the COLMAP model (:mod:`framework.scene.colmap`) and the observed
images as delivered (:mod:`framework.scene.photos`: EXR, PNG, JPEG, masks, undistortion onto
the pinhole cameras). Every problem raises :class:`~framework.errors.SceneError` with one line naming the
file and the fix; nothing in the folder is ever written.
"""
from __future__ import annotations

import hashlib
import os
import sys
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np

from framework.errors import SceneError
from framework.render import sunsky
from framework.scene.colmap import read_model
from framework.scene.exr import read_exr_checked
from framework.scene.model import Emitter, Light, Mesh, Scene
from framework.scene.photos import image_file, read_photos
from framework.scene.emitter_schema import EmitterSpec
from framework.scene.schema import SceneSpec, read_scene_yaml
from framework.scene.values import one_line

__all__ = ["image_file", "load_scene"]     # image_file: where a view's observed image is read

# One redirection of the process's stderr at a time: two threads interleaving their dup2 calls
# would leave stderr pointing at a deleted temporary file.
_STDERR_LOCK = threading.Lock()


def load_scene(directory: str | os.PathLike, *, observations: bool = True) -> Scene:
    """Load and check a scene folder (``docs/scene-format.md``).

    Parameters
    ----------
    directory : path-like
        Folder holding ``scene.yaml``, ``sparse/`` and optionally ``images/``; the meshes may
        lie anywhere ``scene.yaml`` points to.
    observations : bool, default True
        False skips the check that the scene has observations (``images/`` or a reference for
        every kernel): for a folder checked before its photographs or references are added
        (:mod:`framework.convert`).

    Returns
    -------
    Scene

    Raises
    ------
    SceneError
        With one line naming the offending file and the fix.
    """
    root = Path(directory).expanduser().resolve()
    spec = read_scene_yaml(root)
    first = np.cumsum([0] + [2 if e.type == "sunsky" else 1 for e in spec.emitters])   # model index of each
    meshes = tuple(Mesh(path, *_read_mesh(root / path), segment=s, radiance=radiance,
                        emitter=None if source is None else int(first[source]))
                   for path, s, radiance, source in _mesh_table(root, spec))
    _check_surfaces(spec, meshes)
    emitters = tuple(part for i, e in enumerate(spec.emitters) for part in _emitter(root, e, i, spec))
    model = read_model(root)
    _check_reference_view(spec, model)
    lights = _lights(root, spec, [c.name for c in model.cameras], model.files["images"])
    photos = read_photos(root, model.cameras, spec.channels, spec.photometry)
    # a known weight is its own reference (Scene.reference)
    if observations and photos is None and not all(set(s.reference or {}) | set(s.known or {}) == set(s.kernels)
                                                   for s in spec.segments):
        raise SceneError(f"{root}: no images/ folder and not every segment has a reference for each "
                         "kernel; add images/<view> (.exr, .png or .jpg) or references to scene.yaml")
    inputs = _inputs(root, spec, meshes, model.files, photos.files if photos is not None else ())
    return Scene(name=spec.name or root.name, root=root, channels=spec.channels,
                 segments=spec.segments, meshes=meshes, emitters=emitters, cameras=model.cameras,
                 images=None if photos is None else photos.images, content_hash=_content_hash(inputs),
                 pose_source=model.pose_source, weights=None if photos is None else photos.weights,
                 noise=None if photos is None else photos.noise, photometry=spec.photometry,
                 excluded=None if photos is None else photos.excluded,
                 origin=spec.origin, lights=lights)


def _check_reference_view(spec: SceneSpec, model) -> None:
    """``photometry: reference_view`` names an image of the COLMAP model."""
    view = spec.photometry.reference_view
    names = [c.name for c in model.cameras]
    if view is not None and view not in names:
        shown = ", ".join(names[:8]) + (f", ... ({len(names)} images)" if len(names) > 8 else "")
        raise SceneError(f"{spec.path}: photometry reference_view '{view}' is not an image of "
                         f"{model.files['images']}; name one of: {shown}")


def _lights(root: Path, spec: SceneSpec, names: list[str], images: Path) -> tuple[Light, ...]:
    """scene.yaml ``lights`` with their emitters read; every view they name an image of the
    model, and some view left to ``emitters``."""
    for light in spec.lights:
        for v in light.views:
            if v not in names:
                shown = ", ".join(names[:8]) + (f", ... ({len(names)} images)" if len(names) > 8 else "")
                raise SceneError(f"{spec.path}: light '{light.name}' views names {v}, which is not an image of "
                                 f"{images}; name one of: {shown}")
    named = {v for light in spec.lights for v in light.views}
    if spec.lights and named >= set(names):
        raise SceneError(f"{spec.path}: lights name every image of {images}, so emitters light no view; "
                         "emitters are the light of the views no light names: move one light's emitters there "
                         "and its entry out of lights")
    return tuple(Light(light.name, light.views,
                       tuple(part for i, e in enumerate(light.emitters)
                             for part in _emitter(root, e, i, spec, label=f"light '{light.name}' emitter {i}")))
                 for light in spec.lights)


# ----------------------------------------------------------------------------------------------
# Meshes and emitters
# ----------------------------------------------------------------------------------------------

def _mesh_table(root: Path, spec: SceneSpec) -> list[tuple[str, int | None, np.ndarray | None, int | None]]:
    """(path as written, segment index or None, area radiance or None, index of its area emitter
    in scene.yaml or None) of every mesh, segments' meshes first. Meshes are told apart by the
    file they resolve to, so ``./meshes/a.ply`` and ``meshes/a.ply`` are one mesh. A number
    ``scale`` multiplies the radiance."""
    owner: dict[Path, tuple[str, int | None]] = {}
    for s, seg in enumerate(spec.segments):
        for m in seg.meshes:
            file = (root / m).resolve()
            if file in owner:
                raise SceneError(_shared_mesh(spec, m, seg.name, *owner[file]))
            owner[file] = (m, s)
    radiance: dict[Path, tuple[np.ndarray, int]] = {}
    for i, e in enumerate(spec.emitters):
        for m in e.meshes:
            file = (root / m).resolve()
            if file in radiance:
                raise SceneError(f"{spec.path}: mesh {m} is listed twice by area emitters; list it once")
            radiance[file] = (e.radiance * e.scale, i)
            owner.setdefault(file, (m, None))
    return [(m, s, *radiance.get(file, (None, None))) for file, (m, s) in owner.items()]


def _shared_mesh(spec: SceneSpec, m: str, segment: str, first: str, s: int) -> str:
    """The message for a mesh file listed by two segments (or twice by one)."""
    other = spec.segments[s].name
    where = f"twice in segment '{segment}'" if other == segment else f"in segments '{other}' and '{segment}'"
    alias = "" if first == m else f" (as {first} and {m}: the same file)"
    return f"{spec.path}: mesh {first} is {where}{alias}; a mesh belongs to one segment: split it in two files"


def _read_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    if not path.is_file():
        raise SceneError(f"{path}: mesh file missing; fix the path in scene.yaml")
    import open3d as o3d
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    with _c_stderr_captured() as printed:
        mesh = o3d.io.read_triangle_mesh(str(path))
    v = np.asarray(mesh.vertices, dtype=float)
    f = np.asarray(mesh.triangles, dtype=np.int64)
    complaint = one_line(printed[0])            # RPly's own error, if any
    if len(f) == 0:
        why = f": {complaint}" if complaint else ""
        raise SceneError(f"{path}: no triangles (unreadable or empty PLY{why}); export a triangle mesh")
    if complaint:
        raise SceneError(f"{path}: corrupt or truncated PLY ({complaint}); re-export the mesh")
    if not np.isfinite(v).all():
        raise SceneError(f"{path}: vertices with NaN/Inf coordinates; clean the mesh")
    if f.min() < 0 or f.max() >= len(v):
        raise SceneError(f"{path}: face indices out of range; re-export the mesh")
    return v, f.astype(np.int32)


@contextmanager
def _c_stderr_captured() -> Iterator[list[str]]:
    """Redirect the process's stderr (file descriptor 2) to a temporary file; on exit the list
    yielded holds what was printed there.

    Open3D's PLY reader (RPly) prints its errors straight to the C stderr; the user must see
    only our one line, and the text still serves in that line.
    """
    printed: list[str] = []
    sys.stderr.flush()
    with _STDERR_LOCK, tempfile.TemporaryFile() as sink:
        saved = os.dup(2)
        os.dup2(sink.fileno(), 2)
        try:
            yield printed
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            printed.append(sink.read().decode(errors="replace"))


def _check_surfaces(spec: SceneSpec, meshes: tuple[Mesh, ...]) -> None:
    """A segment whose triangles all have zero area has no surface: nothing to estimate."""
    for s, seg in enumerate(spec.segments):
        own = [m for m in meshes if m.segment == s]
        if sum(m.area for m in own) == 0:
            raise SceneError(f"{spec.path}: segment '{seg.name}': all {sum(len(m.faces) for m in own)} "
                             f"triangles of {', '.join(m.path for m in own)} have zero area; fix the mesh")


def _emitter(root: Path, e: EmitterSpec, i: int, spec: SceneSpec, *, label: str | None = None
             ) -> tuple[Emitter, ...]:
    """The model's emitter(s) of scene.yaml's emitter ``i`` (of ``emitters``, or of a light:
    ``label`` names it in messages): one, or a sunsky's sky and sun. A number ``scale`` is applied
    (see :class:`Emitter`)."""
    tag = {"source": i, "scale_unknown": e.scale_unknown}
    if e.type == "sunsky":
        return _sunsky_parts(e.sunsky, i, spec, label or f"emitter {i}")
    if e.type == "envmap":
        image = read_exr_checked(root / e.file, channels=spec.channels)
        return (Emitter(e.type, image=image, scale=e.scale, file=e.file, **tag),)
    if e.type == "area":
        return (Emitter(e.type, radiance=e.radiance * e.scale, **tag),)
    if e.type == "constant":
        return (Emitter(e.type, radiance=e.radiance * e.scale, **tag),)
    return (Emitter(e.type, direction=e.direction, irradiance=e.irradiance * e.scale, **tag),)


def _sunsky_parts(s, i: int, spec: SceneSpec, label: str) -> tuple[Emitter, Emitter]:
    """A ``sunsky``'s sky (``envmap``, baked by :mod:`framework.render.sunsky`, never written
    anywhere) and sun (``directional``); the sun placed from place and time in the world with
    the scene's ``north``, or given."""
    channels = "mono" if spec.channels == ("Y",) else "rgb"
    if s.sun_direction is not None:
        sun = s.sun_direction
    else:
        elevation, azimuth = sunsky.sun_position(s.latitude, s.longitude, s.time)
        if elevation <= 0:
            raise SceneError(f"{spec.path}: {label} (sunsky): the sun is {-elevation:.1f} deg below the "
                             f"horizon at latitude {s.latitude:g}, longitude {s.longitude:g} on "
                             f"{s.time.isoformat()}; check the date, the time and its UTC offset (the sky "
                             "model needs a sun above the horizon)")
        sun = sunsky.sun_vector(elevation, azimuth, north=s.north)
    sky, e_sun = sunsky.sunsky_parts(sun, channels, turbidity=s.turbidity, ground_albedo=s.ground_albedo)
    return (Emitter("envmap", image=sky, scale=s.sky_scale, scale_unknown=s.sky_scale_unknown,
                    source=i, part="sky"),
            Emitter("directional", direction=-sun, irradiance=e_sun * s.sun_scale,
                    scale_unknown=s.sun_scale_unknown, source=i, part="sun"))


# ----------------------------------------------------------------------------------------------
# The content hash
# ----------------------------------------------------------------------------------------------

def _inputs(root: Path, spec: SceneSpec, meshes, model_files: dict[str, Path], photos) -> dict[str, Path]:
    """Every file the loader read, by its name in the scene (as scene.yaml writes it, or relative
    to the folder): the scene description, meshes, environment maps, COLMAP files and the
    observed images and masks (``photos``, the files read)."""
    inputs = {"scene.yaml": spec.path}
    inputs.update({m.path: root / m.path for m in meshes})
    for emitters in (spec.emitters, *(light.emitters for light in spec.lights)):
        inputs.update({e.file: root / e.file for e in emitters if e.type == "envmap"})
    inputs.update({path.relative_to(root).as_posix(): path for path in model_files.values()})
    inputs.update({path.relative_to(root).as_posix(): path for path in photos})
    return inputs


def _content_hash(inputs: dict[str, Path]) -> str:
    """SHA-256 over the files read (names and bytes): the key of every cache entry.

    A file outside the folder (``../x.ply``, an absolute path, a symlinked folder) counts by the
    bytes of the file it resolves to, so editing it renders the observations again; where the
    folder lies does not count, and files the loader does not read (``preview.png``) neither.
    """
    h = hashlib.sha256()
    for name in sorted(inputs):
        h.update(name.encode() + b"\0")
        h.update(hashlib.sha256(inputs[name].read_bytes()).digest())
    return h.hexdigest()[:16]
