"""Writing scene directories (CONTRACT section 1): meshes, COLMAP model, scene.yaml.

Used by the bundled-scene generator and by the tests' tiny scenes.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml


def write_mesh(path: str | Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Write a triangle mesh as binary PLY with Open3D."""
    import open3d as o3d
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(vertices, float)),
                                     o3d.utility.Vector3iVector(np.asarray(faces, np.int32)))
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    if not o3d.io.write_triangle_mesh(str(path), mesh, write_ascii=False):
        raise OSError(f"could not write {path}")


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """COLMAP ``cam_from_world`` (3, 4) of a camera at ``eye`` looking at ``target`` (x right, y down)."""
    eye, target, up = (np.asarray(v, float) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:                 # looking along up: any right vector will do
        x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return np.concatenate([R, -R @ eye[:, None]], axis=1)


def write_colmap(sparse_dir: str | Path, cameras: list[dict]) -> None:
    """Write a COLMAP text model; each camera is a dict with ``name``, ``width``, ``height``,
    ``f``, ``cx``, ``cy`` (pixels) and ``cam_from_world`` (3, 4); ``model`` defaults to PINHOLE
    (``params`` overrides the parameter list, for other models)."""
    import pycolmap
    rec = pycolmap.Reconstruction()
    for i, c in enumerate(cameras, start=1):
        model = c.get("model", "PINHOLE")
        params = c.get("params") or ([c["f"], c["f"], c["cx"], c["cy"]] if model == "PINHOLE"
                                     else [c["f"], c["cx"], c["cy"]])
        cam = pycolmap.Camera(model=model, width=int(c["width"]), height=int(c["height"]),
                              params=params, camera_id=i)
        rec.add_camera_with_trivial_rig(cam)
        T = np.asarray(c["cam_from_world"], float)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(T[:, :3]), T[:, 3])
        rec.add_image_with_trivial_frame(pycolmap.Image(name=c["name"], camera_id=i, image_id=i), pose)
    Path(sparse_dir).mkdir(parents=True, exist_ok=True)
    rec.write_text(str(sparse_dir))


def write_scene_yaml(root: str | Path, description: dict) -> None:
    """Write ``scene.yaml`` (keys in the given order)."""
    Path(root).mkdir(parents=True, exist_ok=True)
    (Path(root) / "scene.yaml").write_text(yaml.safe_dump(description, sort_keys=False))
