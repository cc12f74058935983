"""A camera turned about its centre: the image motion of a small rotation, in pixels.

A camera turned by the rotation ``R`` (``cam_from_world' = R · cam_from_world``, the centre fixed;
:func:`rotated`) sees through pixel ``p`` what the given camera sees through
``q(p) = K Rᵀ K⁻¹ p`` (a homography; ``K`` the pinhole's intrinsics; :func:`project_back`). The
rotation vector ``ω`` is about the camera's x, y, z axes (pitch, yaw, roll); to first order yaw
and pitch shift the image by ``f·ω`` pixels and roll turns it about the principal point
(:func:`pixel_scale`). The registration (:mod:`methods.symbolic.misfit.registration`) solves for
``ω`` with :func:`warp`'s derivatives; :func:`correction` measures the rotation between two
cameras of one centre, as the run reports it.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from framework.scene.model import Camera


def rotated(camera: Camera, rotation: np.ndarray) -> Camera:
    """``camera`` turned about its centre by the rotation vector ``rotation`` (camera axes):
    ``cam_from_world' = R · cam_from_world``."""
    R = rotation_matrix(rotation)
    return dataclasses.replace(camera, cam_from_world=R @ np.asarray(camera.cam_from_world, float))



def rotation_matrix(rotation: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    return Rotation.from_rotvec(np.asarray(rotation, float)).as_matrix()


def pixel_scale(camera: Camera) -> np.ndarray:
    """Pixels of motion per radian: ``f`` for pitch and yaw (at the principal point), the half
    diagonal for roll (at the corner)."""
    return np.array([camera.f, camera.f, 0.5 * np.hypot(camera.width, camera.height)])


def pixel_grid(camera: Camera) -> np.ndarray:
    """``(H·W, 2)`` pixel centres (x, y), row-major."""
    ys, xs = np.mgrid[0:camera.height, 0:camera.width]
    return np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5], axis=1).astype(float)


def project_back(camera: Camera, omega: np.ndarray, px: np.ndarray) -> np.ndarray:
    """``q = K Rᵀ K⁻¹ p``: where the given camera sees what the turned one sees through ``px``."""
    d = np.stack([(px[:, 0] - camera.cx) / camera.f, (px[:, 1] - camera.cy) / camera.f, np.ones(len(px))], axis=1)
    d = d @ rotation_matrix(omega)         # rows: Rᵀ d
    return np.stack([camera.f * d[:, 0] / d[:, 2] + camera.cx, camera.f * d[:, 1] / d[:, 2] + camera.cy], axis=1)


def warp(camera: Camera, omega: np.ndarray, px: np.ndarray, n_par: int) -> tuple[np.ndarray, np.ndarray]:
    """``q(p; ω)`` and ``∂q/∂ω`` per pixel of motion (central differences, ``(n, 2, n_par)``)."""
    q = project_back(camera, omega, px)
    scale = pixel_scale(camera)
    dq = np.empty((len(px), 2, n_par))
    for j in range(n_par):
        h = np.zeros(3)
        h[j] = 1e-4 / scale[j]                 # 1e-4 px of motion
        dq[:, :, j] = (project_back(camera, omega + h, px) - project_back(camera, omega - h, px)) / 2e-4
    return q, dq


def centre_shift(camera: Camera, omega: np.ndarray) -> np.ndarray:
    """The motion ``c - q(c)`` of the content at the principal point ``c``."""
    c = np.array([[camera.cx, camera.cy]])
    return (c - project_back(camera, omega, c))[0]


def correction(given: Camera, camera: Camera) -> dict:
    """The rotation from ``given`` to ``camera`` (same centre): ``shift_px`` (the motion at the
    principal point), ``rotation_deg`` ([pitch, yaw, roll]) and ``motion_px`` (the larger of the
    shift's length and the roll's motion at the corner)."""
    from scipy.spatial.transform import Rotation
    R = np.asarray(camera.cam_from_world, float)[:, :3] @ np.asarray(given.cam_from_world, float)[:, :3].T
    omega = Rotation.from_matrix(R).as_rotvec()
    shift = centre_shift(given, omega)
    roll_px = abs(omega[2]) * pixel_scale(given)[2]
    return {"shift_px": [float(shift[0]), float(shift[1])], "rotation_deg": [float(v) for v in np.degrees(omega)],
            "motion_px": float(max(np.hypot(*shift), roll_px))}
