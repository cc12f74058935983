"""The scene-format writer (``docs/scene-format.md``): meshes, the COLMAP model and ``scene.yaml``.

The counterpart of :mod:`framework.scene.load`, used by the scene builders (``scenes/``) and the
tests' tiny scenes. Views are the model's own :class:`~framework.scene.model.Camera`;
:func:`pinhole_camera` makes one with its principal point at the image centre. EXR files go
through :func:`framework.images.write_exr`.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import yaml

from framework.scene.model import Camera


def write_mesh(path: Path, vertices: np.ndarray, faces: np.ndarray) -> Path:
    """Write a triangle mesh as a binary PLY with Open3D.

    Parameters
    ----------
    path : Path
        Output ``.ply`` file; its folder is created.
    vertices : ndarray, shape (n, 3)
        Vertex positions in metres (world frame, +z up).
    faces : ndarray, shape (m, 3)
        Vertex indices of each triangle, counter-clockwise around the outward normal.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OSError
        If Open3D cannot write the file.
    """
    import open3d as o3d

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(vertices, np.float64)),
                                     o3d.utility.Vector3iVector(np.asarray(faces, np.int32)))
    if not o3d.io.write_triangle_mesh(str(path), mesh, write_ascii=False, compressed=False,
                                      write_vertex_normals=False, write_vertex_colors=False,
                                      write_triangle_uvs=False):
        raise OSError(f"open3d could not write {path}")
    return path


def pinhole_camera(name: str, width: int, height: int, focal: float, cam_from_world: np.ndarray) -> Camera:
    """A view with square pixels and its principal point at the image centre.

    Parameters
    ----------
    name : str
        Image name in ``images.txt`` (e.g. ``street_000.png``).
    width, height : int
        Image size in pixels.
    focal : float
        Focal length in pixels (fx = fy).
    cam_from_world : ndarray, shape (3, 4)
        COLMAP pose [R | t] (camera x right, y down, z forward).

    Returns
    -------
    Camera
        With ``cx = width / 2``, ``cy = height / 2``.
    """
    return Camera(name, width, height, focal, width / 2, height / 2, np.asarray(cam_from_world, float))


def write_colmap(sparse_dir: Path, cameras: Sequence[Camera], points: np.ndarray | None = None,
                 models: Sequence[tuple[str, Sequence[float]] | None] | None = None, *,
                 shared_camera: bool = False) -> Path:
    """Write a text COLMAP model (cameras.txt, images.txt, points3D.txt, ...) with pycolmap.

    Each view gets its own ``PINHOLE`` camera (ids 1..n, in list order) and image of the same id,
    unless ``models`` gives it another COLMAP camera model, or ``shared_camera`` puts every view
    on camera 1.

    Parameters
    ----------
    sparse_dir : Path
        Output folder (created).
    cameras : sequence of Camera
        The views.
    points : ndarray, shape (k, 3), optional
        A few 3D points of the scene for ``points3D.txt`` (empty tracks).
    models : sequence of (str, sequence of float) or None, optional
        One entry per view: a COLMAP camera model name (``SIMPLE_RADIAL``, ``OPENCV``, ...) and
        its full parameter list in COLMAP's order (e.g. ``fx, fy, cx, cy, k1, k2, p1, p2``),
        which replace the view's ``PINHOLE`` intrinsics (its width, height and pose are kept);
        ``None`` (for the list or an entry) keeps ``PINHOLE``.
    shared_camera : bool, default False
        One COLMAP camera (id 1) for every view, as one lens takes them all (views that share a
        camera id share e.g. a vignetting profile): the views must have the same size and
        intrinsics (and ``models`` the same entry), else ``ValueError``. Images keep ids 1..n.

    Returns
    -------
    Path
        ``sparse_dir``.
    """
    import pycolmap

    if models is not None and len(models) != len(cameras):
        raise ValueError(f"write_colmap: {len(models)} camera models for {len(cameras)} views")
    if shared_camera:
        first = _intrinsics(cameras[0], None if models is None else models[0])
        other = [c.name for k, c in enumerate(cameras)
                 if _intrinsics(c, None if models is None else models[k]) != first]
        if other:
            raise ValueError(f"write_colmap: shared_camera, but {', '.join(other)} differ from "
                             f"{cameras[0].name} in size or intrinsics")
    rec = pycolmap.Reconstruction()
    for i, cam in enumerate(cameras, start=1):
        _add_view(rec, i, cam, None if models is None else models[i - 1], camera_id=1 if shared_camera else i)
    for p in (np.zeros((0, 3)) if points is None else np.asarray(points, float)):
        rec.add_point3D(p, pycolmap.Track(), np.array([128, 128, 128], np.uint8))
    sparse_dir = Path(sparse_dir)
    sparse_dir.mkdir(parents=True, exist_ok=True)
    rec.write_text(str(sparse_dir))
    return sparse_dir


def _intrinsics(cam: Camera, model: tuple[str, Sequence[float]] | None) -> tuple:
    """(width, height, COLMAP model name, parameters) of a view as :func:`_add_view` writes it."""
    name, params = ("PINHOLE", [cam.f, cam.f, cam.cx, cam.cy]) if model is None else model
    return int(cam.width), int(cam.height), name, tuple(float(x) for x in params)


def _add_view(rec, i: int, cam: Camera, model: tuple[str, Sequence[float]] | None = None, *,
              camera_id: int | None = None) -> None:
    """Add ``cam`` to the reconstruction ``rec`` as image ``i`` of camera ``camera_id`` (default
    ``i``; added unless ``rec`` has it already). ``model``: another COLMAP model name and its
    parameters instead of ``PINHOLE``."""
    import pycolmap

    camera_id = i if camera_id is None else camera_id
    if camera_id not in rec.cameras:
        width, height, name, params = _intrinsics(cam, model)
        rec.add_camera_with_trivial_rig(pycolmap.Camera(
            model=name, width=width, height=height, params=list(params), camera_id=camera_id))
    pose = pycolmap.Rigid3d(pycolmap.Rotation3d(np.asarray(cam.cam_from_world[:, :3], float)),
                            np.asarray(cam.cam_from_world[:, 3], float))
    rec.add_image_with_trivial_frame(pycolmap.Image(name=cam.name, camera_id=camera_id, image_id=i), pose)


def write_scene_yaml(path: Path, scene: dict, comment: str = "") -> Path:
    """Write ``scene.yaml`` with a leading comment block.

    Parameters
    ----------
    path : Path
        Output file.
    scene : dict
        ``name``, ``channels``, ``segments``, ``emitters``; numpy values are written as plain
        numbers (floats rounded to 7 decimals).
    comment : str
        Free text written as ``#`` comment lines above the data (units, scales, provenance).

    Returns
    -------
    Path
        ``path``.
    """
    head = "".join(f"# {line}".rstrip() + "\n" for line in comment.strip().splitlines()) if comment else ""
    body = yaml.safe_dump(_plain(scene), sort_keys=False, default_flow_style=None, width=100)
    Path(path).write_text(head + body)
    return Path(path)


def _plain(x):
    """Recursively convert numpy scalars/arrays to Python floats/lists (rounded for readability)."""
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_plain(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return float(round(float(x), 7))
    if isinstance(x, np.integer):
        return int(x)
    return x
