"""Writers (and a few readers) for the pieces of a scene folder: meshes, COLMAP, scene.yaml.

EXR files go through :mod:`framework.images`. Used by the bundled scenes and the tests' tiny scenes.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml


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


def read_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a PLY with Open3D; (vertices (n, 3), faces (m, 3)). Raises if the file is missing."""
    import open3d as o3d

    if not Path(path).is_file():
        raise FileNotFoundError(path)
    mesh = o3d.io.read_triangle_mesh(str(path))
    return np.asarray(mesh.vertices), np.asarray(mesh.triangles)


@dataclass(frozen=True)
class PinholeCamera:
    """One posed pinhole view, as written to the COLMAP model.

    Attributes
    ----------
    name : str
        Image name in ``images.txt`` (e.g. ``street_000.png``).
    width, height : int
        Image size in pixels.
    focal : float
        Focal length in pixels (fx = fy); the principal point is the image centre.
    cam_from_world : ndarray, shape (3, 4)
        COLMAP pose [R | t] (camera x right, y down, z forward).
    """

    name: str
    width: int
    height: int
    focal: float
    cam_from_world: np.ndarray

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (n, 2) (COLMAP convention: pixel centres at +0.5) and depths (n,)."""
        p = np.atleast_2d(points) @ self.cam_from_world[:, :3].T + self.cam_from_world[:, 3]
        uv = self.focal * p[:, :2] / p[:, 2:3] + np.array([self.width, self.height]) / 2
        return uv, p[:, 2]


def write_colmap(sparse_dir: Path, cameras: list[PinholeCamera],
                 points: np.ndarray | None = None) -> Path:
    """Write a text COLMAP model (cameras.txt, images.txt, points3D.txt, ...) with pycolmap.

    Each view gets its own ``PINHOLE`` camera (ids 1..n, in list order) and image of the same id.

    Parameters
    ----------
    sparse_dir : Path
        Output folder (created).
    cameras : list of PinholeCamera
        The views.
    points : ndarray, shape (k, 3), optional
        A few 3D points of the scene for ``points3D.txt`` (empty tracks).
    """
    import pycolmap

    rec = pycolmap.Reconstruction()
    for i, cam in enumerate(cameras, start=1):
        c = cam.width / 2, cam.height / 2
        rec.add_camera_with_trivial_rig(pycolmap.Camera(
            model="PINHOLE", width=cam.width, height=cam.height,
            params=[cam.focal, cam.focal, c[0], c[1]], camera_id=i))
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(np.asarray(cam.cam_from_world[:, :3], float)),
                                np.asarray(cam.cam_from_world[:, 3], float))
        rec.add_image_with_trivial_frame(pycolmap.Image(name=cam.name, camera_id=i, image_id=i), pose)
    for p in (np.zeros((0, 3)) if points is None else np.asarray(points, float)):
        rec.add_point3D(p, pycolmap.Track(), np.array([128, 128, 128], np.uint8))
    sparse_dir = Path(sparse_dir)
    sparse_dir.mkdir(parents=True, exist_ok=True)
    rec.write_text(str(sparse_dir))
    return sparse_dir


def read_colmap(sparse_dir: Path) -> list[PinholeCamera]:
    """Read the views of a COLMAP model back as :class:`PinholeCamera` (sorted by image id).

    Only ``PINHOLE`` with fx = fy and ``SIMPLE_PINHOLE`` cameras with a centred principal point
    are expected here (the bundled scenes write no other).
    """
    import pycolmap

    rec = pycolmap.Reconstruction(str(sparse_dir))
    out = []
    for iid in sorted(rec.images):
        im = rec.images[iid]
        cam = rec.cameras[im.camera_id]
        out.append(PinholeCamera(im.name, cam.width, cam.height, float(cam.focal_length_x),
                                 np.asarray(im.cam_from_world().matrix())))
    return out


def write_scene_yaml(path: Path, scene: dict, comment: str = "") -> Path:
    """Write ``scene.yaml`` (``docs/scene-format.md``) with a leading comment block.

    Parameters
    ----------
    path : Path
        Output file.
    scene : dict
        ``name``, ``channels``, ``segments``, ``emitters`` (plain Python types).
    comment : str
        Free text written as ``#`` comment lines above the data (units, scales, provenance).
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
