"""The lens falloff of scene.yaml ``photometry: vignetting`` (docs/scene-format.md): a pixel is
``V(r) · radiance`` with ``V(r) = 1 + a1 r² + a2 r⁴ + a3 r⁶``. One definition for the symbolic
fit (:mod:`methods.symbolic.survey.vignetting`, where the model is explained) and for the observations
rendered from a scene's references (:mod:`framework.observe`), so that both see the same lens.
"""
from __future__ import annotations

import numpy as np


def pixel_radius(camera) -> np.ndarray:
    """``(H·W,)`` ``r`` of each pixel of ``camera`` (a :class:`~framework.scene.model.Camera`),
    row-major: the distance of the pixel centre, in the delivered image, from the principal
    point over half the image diagonal (:mod:`methods.symbolic.survey.vignetting`)."""
    h, w = int(camera.height), int(camera.width)
    if getattr(camera, "distortion", None) is None:
        xs, ys = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
        x, y, cx, cy = xs.ravel(), ys.ravel(), float(camera.cx), float(camera.cy)
    else:
        from framework.scene.undistort import source_pixels
        delivered = camera.delivered()
        at = source_pixels(source=delivered, target=camera.pinhole()).reshape(-1, 2)
        x, y = at[:, 0], at[:, 1]
        cx, cy = float(delivered.principal_point_x), float(delivered.principal_point_y)
    return np.hypot(x - cx, y - cy) / (0.5 * np.hypot(w, h))


def falloff(r: np.ndarray, profile) -> np.ndarray:
    """``V(r) = 1 + a1 r² + a2 r⁴ + a3 r⁶`` for ``profile = (a1, a2, a3)``."""
    r2 = np.asarray(r, float) ** 2
    a1, a2, a3 = (float(a) for a in profile)
    return 1.0 + r2 * (a1 + r2 * (a2 + r2 * a3))
