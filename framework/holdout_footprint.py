"""The resampling a held-out photograph went through, applied to its prediction.

A photograph of a distorted camera was resampled by the loader onto its pinhole camera
(:class:`framework.scene.undistort.Resampling`): a pinhole pixel is a weighted sum of source
pixels, each the mean radiance over a parallelogram of the pinhole image
(:class:`framework.scene.undistort.Footprint`), so it carries the interpolation's blur. The
prediction of such a view is a ``path`` render of the pinhole camera at :data:`SUPERSAMPLE`
times its resolution (the same samples per pinhole pixel in all), integrated over the same
footprint (:data:`GRID` x :data:`GRID` points per parallelogram, read bilinearly from the fine
image), as the symbolic method's footprint does for the fitted views.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from framework.relight import render_relit

#: Pinhole pixels per side rendered per pixel of the view before the footprint is applied.
SUPERSAMPLE = 4
#: Points per side read in each source pixel's parallelogram.
GRID = 4
#: Pixels integrated at a time (bounds the memory of the lookups).
CHUNK = 4096


def resampled(scene, camera) -> bool:
    """Whether the loader resampled ``camera``'s photograph from a distorted camera."""
    return scene.images is not None and getattr(camera, "distortion", None) is not None


def fine_camera(camera, s: int):
    """``camera`` at ``s`` times its resolution (same pose and projection), as a pinhole."""
    return dataclasses.replace(camera, width=camera.width * s, height=camera.height * s, f=camera.f * s,
                               cx=camera.cx * s, cy=camera.cy * s, distortion=None)


def _bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``image`` (H, W, C) at continuous coordinates (centres at .5), clamped at the border."""
    h, w = image.shape[:2]
    x, y = np.clip(x - 0.5, 0, w - 1), np.clip(y - 0.5, 0, h - 1)
    x0, y0 = np.minimum(np.floor(x).astype(int), max(w - 2, 0)), np.minimum(np.floor(y).astype(int), max(h - 2, 0))
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    return ((1 - fy) * ((1 - fx) * image[y0, x0] + fx * image[y0, x1])
            + fy * ((1 - fx) * image[y1, x0] + fx * image[y1, x1]))


def integrate(fine: np.ndarray, footprint, camera, s: int) -> np.ndarray:
    """``(H, W, C)``: each pixel of ``camera`` as ``sum_k weight[k]`` times the mean of ``fine``
    (the view at ``s`` times its resolution) over its ``k``-th source parallelogram."""
    u = (np.arange(GRID) + 0.5) / GRID - 0.5
    du = np.stack(np.meshgrid(u, u), axis=-1).reshape(-1, 2)                    # (G², 2)
    n = len(footprint.weight)
    out = np.empty((n, fine.shape[-1]))
    for a in range(0, n, CHUNK):                     # a chunk's points: CHUNK x K x G² x C values
        b = min(a + CHUNK, n)
        offsets = np.einsum("nij,gj->ngi", footprint.jacobian[a:b], du)                  # (n, G², 2)
        points = footprint.position[a:b, :, None, :] + offsets[:, None, :, :]           # (n, K, G², 2)
        values = _bilinear(fine, s * points[..., 0], s * points[..., 1]).mean(axis=2)   # (n, K, C)
        out[a:b] = np.einsum("nk,nkc->nc", footprint.weight[a:b], values)
    return out.reshape(camera.height, camera.width, -1).astype(np.float32)


def render_resampled(scene, cameras, rho, params, *, spp: int, seed: int, max_depth: int) -> dict:
    """:func:`framework.relight.render_relit` of ``cameras``, the resampled ones
    (:func:`resampled`) through their photographs' footprint."""
    from framework.scene.undistort import Resampling
    plain = [c for c in cameras if not resampled(scene, c)]
    out = render_relit(scene, plain, rho, params, spp=spp, seed=seed, max_depth=max_depth) if plain else {}
    s = SUPERSAMPLE
    for i, cam in enumerate(c for c in cameras if resampled(scene, c)):
        fine = render_relit(scene, [fine_camera(cam, s)], rho, params, spp=max(1, spp // (s * s)),
                            seed=seed + len(cameras) + i, max_depth=max_depth)[cam.name]
        footprint = Resampling(source=cam.delivered(), target=cam.pinhole(),
                               kernel=scene.photometry.resampling).footprint()
        out[cam.name] = integrate(fine, footprint, cam, s)
    return out
