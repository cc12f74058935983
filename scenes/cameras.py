"""Camera poses: look-at in COLMAP convention, and conversion from a Mitsuba sensor ``to_world``."""
from __future__ import annotations

import numpy as np

from scenes.io import PinholeCamera


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
    """Focal length in pixels for a horizontal field of view ``fov_deg`` over ``width`` pixels."""
    return width / (2 * np.tan(np.radians(fov_deg) / 2))


def fov_from_focal(width: int, focal: float) -> float:
    """Horizontal field of view (degrees) of ``focal`` pixels over ``width`` pixels."""
    return float(np.degrees(2 * np.arctan(width / (2 * focal))))


def cam_from_mitsuba(to_world: np.ndarray) -> np.ndarray:
    """COLMAP ``cam_from_world`` (3, 4) of a Mitsuba sensor ``to_world`` (4, 4; x left, y up).

    Inverse of ``to_world = inv(T) @ diag(-1, -1, 1, 1)``.
    """
    world_from_cam = np.asarray(to_world, float) @ np.diag([-1.0, -1.0, 1.0, 1.0])
    return np.linalg.inv(world_from_cam)[:3]


def mitsuba_to_world(cam: PinholeCamera) -> np.ndarray:
    """Mitsuba sensor ``to_world`` (4, 4) of a COLMAP view (the relation of :func:`framework.render.mitsuba_scene.sensor_dict`)."""
    t = np.eye(4)
    t[:3] = cam.cam_from_world
    return np.linalg.inv(t) @ np.diag([-1.0, -1.0, 1.0, 1.0])


def perspective_sensor(cam: PinholeCamera, spp: int = 16, seed: int = 0) -> dict:
    """Mitsuba ``perspective`` sensor dict of a centred-principal-point view (box filter)."""
    import mitsuba as mi

    return {"type": "perspective", "fov": fov_from_focal(cam.width, cam.focal), "fov_axis": "x",
            "to_world": mi.ScalarTransform4f(mitsuba_to_world(cam).tolist()),
            "near_clip": 0.01, "far_clip": 1e5,
            "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
            "film": {"type": "hdrfilm", "width": cam.width, "height": cam.height,
                     "rfilter": {"type": "box"},
                     "pixel_format": "luminance" if "mono" in mi.variant() else "rgb"}}
