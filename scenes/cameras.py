"""Camera poses and intrinsics for the scene builders, in the conventions of the framework.

Poses are COLMAP ``cam_from_world`` (3, 4) (x right, y down, z forward) and focal lengths are in
pixels along x: the inverses of what :func:`framework.render.mitsuba_scene.sensor_dict` does with
a :class:`~framework.scene.model.Camera` (``to_world = inv([R|t]) @ diag(-1, -1, 1, 1)``,
``fov = 2 atan(w / 2f)`` along x).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from framework.scene import Camera


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """COLMAP ``cam_from_world`` (3, 4) of a camera at ``eye`` looking at ``target``.

    The camera frame is x right, y down, z forward; ``up`` is the world direction that appears
    up in the image.
    """
    eye, target, up = (np.asarray(a, float) for a in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rot = np.stack([x, y, z])
    return np.concatenate([rot, (-rot @ eye)[:, None]], axis=1)


def focal_from_fov(width: int, fov_deg: float) -> float:
    """Focal length in pixels for a horizontal field of view ``fov_deg`` over ``width`` pixels
    (the inverse of ``sensor_dict``'s ``fov``)."""
    return width / (2 * np.tan(np.radians(fov_deg) / 2))


def cam_from_mitsuba(to_world: np.ndarray) -> np.ndarray:
    """COLMAP ``cam_from_world`` (3, 4) of a Mitsuba sensor ``to_world`` (4, 4; x left, y up).

    The inverse of ``sensor_dict``'s ``to_world = inv([R|t]) @ diag(-1, -1, 1, 1)``.
    """
    world_from_cam = np.asarray(to_world, float) @ np.diag([-1.0, -1.0, 1.0, 1.0])
    return np.linalg.inv(world_from_cam)[:3]


def resized(camera: Camera, width: int | None) -> Camera:
    """The same view ``width`` pixels wide: same pose and field of view, intrinsics scaled.

    The height is scaled by the same factor (rounded, at least 1 pixel); ``None`` or the
    camera's own width returns ``camera``.
    """
    if width is None or width == camera.width:
        return camera
    s = width / camera.width
    height = max(1, round(camera.height * s))
    return replace(camera, width=width, height=height, f=camera.f * s,
                   cx=camera.cx * s, cy=camera.cy * height / camera.height)
