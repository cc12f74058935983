"""Which pixels of two views see the same point of the model.

For every pixel of view ``v`` the model surface point ``X`` its centre ray hits (a shape of some
segment), and for every other view ``u``: ``X`` projected into ``u`` (the nearest pixel ``q``),
kept when ``u`` sees ``X`` unoccluded in the model: ``X`` faces ``u``'s centre and a shadow ray from
``X`` to that centre reaches it (Mitsuba's ``ray_test``; exact, so no depth tolerance is needed
on oblique surfaces). An object the model lacks (a parked van) does not occlude here: that is
the point, the other views then show the surface behind it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from framework.scene import Camera, Scene

#: a shadow ray starts this far (metres) off the surface, along the normal, and stops as far
#: short of the camera (against self-intersection in float32)
OFFSET_M = 1e-3


@dataclass(frozen=True)
class Surface:
    """The model surface seen through each pixel centre of one view (row-major pixels)."""

    points: np.ndarray     # (n, 3) float64 world points; NaN where no segment is hit
    normals: np.ndarray    # (n, 3) unit geometric normals facing the camera; NaN where none
    segment: np.ndarray    # (n,) int32, -1 where no segment is hit


def camera_centre(camera: Camera) -> np.ndarray:
    """The world position of the camera's centre, ``-Rᵀ t``."""
    R, t = camera.cam_from_world[:, :3], camera.cam_from_world[:, 3]
    return -R.T @ t


def visible_pairs(scene: Scene, cameras: list[Camera]
                  ) -> tuple[list[Surface], dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]]:
    """The :class:`Surface` of every camera, and ``(v, u) -> (p, q)``: the pixels ``p`` of view
    ``v`` whose surface point view ``u`` sees unoccluded, at its nearest pixel ``q`` (module
    docstring), for every ordered pair ``v != u`` that shares any."""
    from framework.render.mitsuba_scene import MitsubaScene
    ms = MitsubaScene(scene, list(cameras), spp=1)
    surf = [_surface(ms, v) for v in range(len(cameras))]
    pairs = {}
    for v, sv in enumerate(surf):
        for u, cam in enumerate(cameras):
            if u != v:
                p, q = _seen_from(ms, sv, cam)
                if len(p):
                    pairs[(v, u)] = (p, q)
    return surf, pairs


def _surface(ms, v: int) -> Surface:
    """The surface seen through view ``v``'s pixel centres."""
    ray, si, seg = ms.centre_hits(v)
    hit = np.array(si.is_valid()) & (seg >= 0)
    p = np.array(si.p, dtype=np.float64).reshape(3, -1).T
    n = np.array(si.n, dtype=np.float64).reshape(3, -1).T
    d = np.array(ray.d, dtype=np.float64).reshape(3, -1).T
    n = np.where((np.sum(n * d, axis=1) > 0)[:, None], -n, n)          # facing the camera
    p[~hit], n[~hit] = np.nan, np.nan
    return Surface(p, n, np.where(hit, seg, -1).astype(np.int32))


def _seen_from(ms, sv: Surface, cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """``(p, q)``: the pixels of ``sv`` whose point ``cam`` sees unoccluded, and its pixel there."""
    import mitsuba as mi
    hit = np.flatnonzero(np.isfinite(sv.points[:, 0]))
    X, N = sv.points[hit], sv.normals[hit]
    c = camera_centre(cam)
    facing = np.sum(N * (c - X), axis=1) > 0
    xy, in_front = _project(cam, X)
    inside = in_front & facing & (xy[:, 0] >= 0) & (xy[:, 0] < cam.width) & (xy[:, 1] >= 0) & (xy[:, 1] < cam.height)
    idx = np.flatnonzero(inside)
    if len(idx) == 0:
        return idx, idx
    start = X[idx] + OFFSET_M * N[idx]
    to_c = c - start
    dist = np.linalg.norm(to_c, axis=1)
    d = to_c / dist[:, None]
    ray = mi.Ray3f(mi.Ray3f(mi.Point3f(*start.T.astype(np.float32)), mi.Vector3f(*d.T.astype(np.float32))),
                   mi.Float((dist - OFFSET_M).astype(np.float32)))
    idx = idx[~np.array(ms.scene.ray_test(ray), dtype=bool)]
    q = np.floor(xy[idx, 1]).astype(np.int64) * cam.width + np.floor(xy[idx, 0]).astype(np.int64)
    return hit[idx], q


def _project(camera: Camera, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (x right, y down; pixel centres at .5) of world points and whether they
    lie in front of the camera."""
    pc = X @ camera.cam_from_world[:, :3].T + camera.cam_from_world[:, 3]
    z = pc[:, 2]
    safe = np.where(z > 1e-9, z, 1.0)
    xy = np.stack([camera.f * pc[:, 0] / safe + camera.cx, camera.f * pc[:, 1] / safe + camera.cy], axis=1)
    return xy, z > 1e-9
