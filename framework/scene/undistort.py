"""Resampling images between COLMAP cameras of one pose, in floating point.

A field photograph comes from a distorted camera (COLMAP's ``SIMPLE_RADIAL``, ``RADIAL``,
``OPENCV``, possibly ``fx != fy``); the renderer has pinhole cameras of square pixels. The
loader resamples each photograph and its mask onto :func:`pinhole_for`'s camera with
:func:`resample`; the scene builders use the same function the other way, to distort a pinhole
render. pycolmap maps pixels to normalised rays and back (its own distortion model, so the two
directions agree with COLMAP); only the interpolation is ours, in float64, because pycolmap's
``undistort_image`` goes through 8-bit bitmaps.
"""
from __future__ import annotations

import numpy as np

#: COLMAP camera models the loader resamples (pinhole ones need no resampling unless fx != fy)
DISTORTED_MODELS = ("SIMPLE_RADIAL", "RADIAL", "OPENCV")
PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")


def pinhole_for(camera):
    """The undistorted pinhole camera a photograph of ``camera`` is resampled onto.

    Same width, height and principal point; one focal length ``f = max(fx, fy)``: with no
    distortion every pinhole pixel then falls inside the delivered image (the narrower field of
    view), and square pixels are what Mitsuba's perspective sensor has. Pixels whose source lies
    outside the delivered image (pincushion corners) are reported by :func:`resample` as invalid.

    Parameters
    ----------
    camera : pycolmap.Camera

    Returns
    -------
    pycolmap.Camera
        A ``PINHOLE`` camera with ``fx == fy``.
    """
    import pycolmap
    f = max(float(camera.focal_length_x), float(camera.focal_length_y))
    return pycolmap.Camera(model="PINHOLE", width=int(camera.width), height=int(camera.height),
                           params=[f, f, float(camera.principal_point_x), float(camera.principal_point_y)])


def source_pixels(*, source, target) -> np.ndarray:
    """``(H_t, W_t, 2)`` continuous pixel coordinates (x right, y down, centres at .5) in
    ``source``'s image of the ray through each pixel centre of ``target`` (same pose)."""
    h, w = int(target.height), int(target.width)
    xs, ys = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    pixels = np.stack([xs.ravel(), ys.ravel()], axis=1)
    rays = np.asarray(target.cam_from_img(pixels), dtype=np.float64)          # normalised (x/z, y/z)
    points = np.concatenate([rays, np.ones((len(rays), 1))], axis=1)
    return np.asarray(source.img_from_cam(points), dtype=np.float64).reshape(h, w, 2)


def resample(image: np.ndarray, *, source, target, valid: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
    """Resample ``image`` taken by ``source`` onto the pixel grid of ``target`` (same pose).

    Bilinear interpolation in float64 of linear values (never encoded ones: interpolating sRGB
    codes would bias the radiance).

    Parameters
    ----------
    image : numpy.ndarray
        ``(H_s, W_s)`` or ``(H_s, W_s, C)`` linear values.
    source, target : pycolmap.Camera
    valid : numpy.ndarray, optional
        ``(H_s, W_s)`` bool: source pixels that may be used (mask, saturation); default all.

    Returns
    -------
    (resampled, ok)
        ``resampled``: ``(H_t, W_t[, C])`` float64; ``ok``: ``(H_t, W_t)`` bool, True where all
        four source pixels of the interpolation lie inside the image and are valid (elsewhere
        ``resampled`` is 0).
    """
    image = np.asarray(image, dtype=np.float64)
    flat = image[..., None] if image.ndim == 2 else image
    hs, ws = flat.shape[:2]
    valid = np.ones((hs, ws), bool) if valid is None else np.asarray(valid, bool)
    at = source_pixels(source=source, target=target) - 0.5        # pixel centres at integers
    x0, y0 = np.floor(at[..., 0]), np.floor(at[..., 1])
    fx, fy = at[..., 0] - x0, at[..., 1] - y0
    inside = np.isfinite(x0) & np.isfinite(y0) & (x0 >= 0) & (y0 >= 0) & (x0 <= ws - 2) & (y0 <= hs - 2)
    xi = np.where(inside, x0, 0).astype(np.int64)
    yi = np.where(inside, y0, 0).astype(np.int64)
    fx, fy = np.where(inside, fx, 0.0), np.where(inside, fy, 0.0)
    out = np.zeros(at.shape[:2] + flat.shape[2:])
    ok = inside.copy()
    for dy, dx, weight in ((0, 0, (1 - fx) * (1 - fy)), (0, 1, fx * (1 - fy)),
                           (1, 0, (1 - fx) * fy), (1, 1, fx * fy)):
        out += weight[..., None] * flat[yi + dy, xi + dx]
        ok &= valid[yi + dy, xi + dx]
    out[~ok] = 0.0
    return (out[..., 0] if image.ndim == 2 else out), ok
