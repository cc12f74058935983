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

from dataclasses import dataclass

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


def _keys(t: np.ndarray) -> list:
    """Keys' cubic convolution weights (a = -0.5) of the pixels at offsets -1, 0, 1, 2 from the
    one below a position ``t`` in [0, 1] past it (they sum to 1; 1 at offset 0 for ``t`` = 0)."""
    t2, t3 = t * t, t * t * t
    return [0.5 * (-t3 + 2 * t2 - t), 0.5 * (3 * t3 - 5 * t2 + 2), 0.5 * (-3 * t3 + 4 * t2 + t), 0.5 * (t3 - t2)]


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
        ``resampled``: ``(H_t, W_t[, C])`` float64; ``ok``: ``(H_t, W_t)`` bool, True where the
        point sampled lies between the source's outer pixel centres and every source pixel
        the interpolation weighs (up to four) is valid (elsewhere ``resampled`` is 0).
    """
    return Resampling(source=source, target=target).apply(image, valid=valid)


@dataclass(frozen=True)
class Footprint:
    """The source pixels behind resampled target pixels, in target coordinates
    (:meth:`Resampling.footprint`): a resampled pixel is ``sum_k weight[k]`` times the mean
    radiance over the parallelogram ``position[k] + jacobian @ [-1/2, 1/2]^2``.

    Attributes
    ----------
    position : numpy.ndarray
        ``(N, K, 2)`` target coordinates (x right, y down, centres at .5) of the ``K`` source
        pixel centres each of ``N`` target pixels weighs.
    weight : numpy.ndarray
        ``(N, K)`` their interpolation weights (sum 1; Keys' cubic has negative ones).
    jacobian : numpy.ndarray
        ``(N, 2, 2)`` d(target) / d(source) at the point each target pixel samples: a source
        pixel's sides in the target, the same for its ``K`` source pixels (the mapping is
        linearised over the few pixels a kernel spans).
    """

    position: np.ndarray
    weight: np.ndarray
    jacobian: np.ndarray


def resampling_key(camera, kernel: str) -> tuple:
    """What a camera's :class:`Resampling` depends on (its lens, size and pinhole, and the
    interpolation ``kernel``): views whose keys are equal share one."""
    return (camera.distortion, camera.width, camera.height, camera.f, camera.cx, camera.cy, kernel)


class Resampling:
    """The interpolation from ``source``'s pixels to ``target``'s (same pose), computed once and
    applied to an image, its validity and the standard deviation of its noise.

    A target pixel centre is mapped to a continuous source position (:func:`source_pixels`);
    positions up to :data:`EDGE` outside the outer pixel centres count as on them (round-off of
    an identity mapping), fractions within :data:`SNAP` of 0 or 1 as exact, so that a source
    pixel of weight 0 does not invalidate its neighbour.

    Parameters
    ----------
    source, target : pycolmap.Camera
    kernel : {"bilinear", "cubic"}
        ``bilinear`` (default): the 2 x 2 source pixels around the position. ``cubic``: Keys'
        cubic convolution with a = -0.5 (Catmull-Rom, 4 x 4 pixels, interpolating), which blurs
        less: at a half-pixel offset (weights 1/2, 1/2 against -1/16, 9/16, 9/16, -1/16, by hand)
        bilinear keeps cos(π f) of a pattern of f cycles a pixel, cubic
        2 (9/16 cos(π f) - 1/16 cos(3π f)): 0.50 against 0.69 at a period of 3 pixels, 0.71
        against 0.88 at 4.
        Near the image border, where the 4 x 4 would leave the image, cubic falls back to bilinear.
    """

    EDGE = 1e-6
    SNAP = 1e-9
    KERNELS = ("bilinear", "cubic")

    def __init__(self, *, source, target, kernel: str = "bilinear"):
        if kernel not in self.KERNELS:
            raise ValueError(f"kernel={kernel!r}: must be one of {', '.join(self.KERNELS)}")
        self.shape = (int(source.height), int(source.width))
        hs, ws = self.shape
        at = source_pixels(source=source, target=target) - 0.5       # pixel centres at integers
        x, y = at[..., 0], at[..., 1]
        with np.errstate(invalid="ignore"):
            self.inside = (np.isfinite(x) & np.isfinite(y) & (x >= -self.EDGE) & (y >= -self.EDGE)
                           & (x <= ws - 1 + self.EDGE) & (y <= hs - 1 + self.EDGE))
        x = np.clip(np.where(self.inside, x, 0.0), 0, ws - 1)
        y = np.clip(np.where(self.inside, y, 0.0), 0, hs - 1)
        x0 = np.clip(np.floor(x), 0, max(ws - 2, 0))
        y0 = np.clip(np.floor(y), 0, max(hs - 2, 0))
        self.kernel, self.source, self.target = kernel, source, target
        #: per target pixel: the source pixel below and left of the position, the fractions past it
        self._base = (x0.astype(np.int64), y0.astype(np.int64), self._snap(x - x0), self._snap(y - y0))
        self._all_taps = None

    @property
    def taps(self) -> list:
        """(row index, column index, weight) of the source pixels each target pixel weighs, each
        ``(H_t, W_t)``; made on first use (24 bytes a pixel and tap: the pass's
        :meth:`footprint` takes a tile's at a time instead)."""
        if self._all_taps is None:
            self._all_taps = self._taps(*self._base, self.kernel)
        return self._all_taps

    def _taps(self, xi, yi, fx, fy, kernel: str) -> list:
        hs, ws = self.shape
        if kernel == "bilinear":
            wx, wy, offsets = [1 - fx, fx], [1 - fy, fy], (0, 1)
        else:
            # the 4 x 4 needs x0 - 1 .. x0 + 2 inside; elsewhere the bilinear weights, on the same taps
            full = (xi >= 1) & (xi <= ws - 3) & (yi >= 1) & (yi <= hs - 3)
            wx = [np.where(full, k, b) for k, b in zip(_keys(fx), [0 * fx, 1 - fx, fx, 0 * fx])]
            wy = [np.where(full, k, b) for k, b in zip(_keys(fy), [0 * fy, 1 - fy, fy, 0 * fy])]
            offsets = (-1, 0, 1, 2)
        taps = []
        for j, dy in enumerate(offsets):
            for i, dx in enumerate(offsets):
                taps.append((np.clip(yi + dy, 0, hs - 1), np.clip(xi + dx, 0, ws - 1), wx[i] * wy[j]))
        return taps

    def footprint(self, start: int = 0, stop: int | None = None) -> "Footprint":
        """Where the resampled values of the target pixels ``[start, stop)`` (row-major) come
        from, in the target's own image: the :class:`Footprint` a renderer of the target camera
        integrates over to predict them (the source pixels' centres, their weights and
        the shape of a source pixel there), so the prediction carries the interpolation's blur.

        A source pixel is the image of a unit box around its centre; in the target it is
        ``jacobian @ box`` around ``position`` (the mapping linearised at the point the target
        pixel samples: over a pixel the lenses of the bundled ``urban_canyon_field``, k1 about
        -0.1 on 200 px images, depart from it by at most 1.3e-3 px, measured at the corners; the
        departure shrinks as 1 / width on larger images of the same lens). Target pixels outside
        the delivered image keep their own box (they are never used).
        """
        n = self.inside.size
        stop = n if stop is None else stop
        if not 0 <= start <= stop <= n:
            raise ValueError(f"pixels [{start}, {stop}) outside the target's {n}")
        base = [a.ravel()[start:stop] for a in self._base]
        taps = self._taps(*base, self.kernel)
        inside = self.inside.ravel()[start:stop]
        centres = np.stack([np.stack([xi + 0.5, yi + 0.5], axis=-1) for yi, xi, _ in taps], axis=1)
        position = self._to_target(centres.reshape(-1, 2)).reshape(centres.shape)
        weight = np.stack([w for _, _, w in taps], axis=1)
        at = np.stack([base[0] + base[2] + 0.5, base[1] + base[3] + 0.5], axis=-1)   # the point sampled
        h = 0.25
        jacobian = np.stack([(self._to_target(at + h * e) - self._to_target(at - h * e)) / (2 * h)
                             for e in (np.array([1.0, 0.0]), np.array([0.0, 1.0]))], axis=-1)
        own = np.stack([np.arange(start, stop) % int(self.target.width) + 0.5,
                        np.arange(start, stop) // int(self.target.width) + 0.5], axis=-1)
        position = np.where(inside[:, None, None], position, own[:, None, :])
        weight = np.where(inside[:, None], weight, np.eye(1, weight.shape[1])[0])
        jacobian = np.where(inside[:, None, None], jacobian, np.eye(2))
        return Footprint(position, weight, jacobian)

    def _to_target(self, pixels: np.ndarray) -> np.ndarray:
        """Continuous target coordinates (centres at .5) of source coordinates ``(N, 2)``."""
        rays = np.asarray(self.source.cam_from_img(pixels), dtype=np.float64)
        points = np.concatenate([rays, np.ones((len(rays), 1))], axis=1)
        return np.asarray(self.target.img_from_cam(points), dtype=np.float64)

    @classmethod
    def _snap(cls, frac: np.ndarray) -> np.ndarray:
        return np.where(frac < cls.SNAP, 0.0, np.where(frac > 1 - cls.SNAP, 1.0, frac))

    def ok(self, valid: np.ndarray | None = None) -> np.ndarray:
        """``(H_t, W_t)`` bool: inside, and every source pixel of non-zero weight valid."""
        ok = self.inside.copy()
        if valid is not None:
            valid = np.asarray(valid, bool)
            for yi, xi, w in self.taps:
                ok &= valid[yi, xi] | (w == 0)
        return ok

    def apply(self, image: np.ndarray, *, valid: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(resampled, ok)`` as :func:`resample` returns them."""
        image = np.asarray(image, dtype=np.float64)
        flat = image[..., None] if image.ndim == 2 else image
        if flat.shape[:2] != self.shape:
            raise ValueError(f"image is {flat.shape[1]}x{flat.shape[0]}, its camera {self.shape[1]}x{self.shape[0]}")
        out = np.zeros(self.inside.shape + flat.shape[2:])
        for yi, xi, w in self.taps:
            out += w[..., None] * flat[yi, xi]
        ok = self.ok(valid)
        out[~ok] = 0.0
        return (out[..., 0] if image.ndim == 2 else out), ok

    def apply_std(self, std: np.ndarray) -> np.ndarray:
        """The standard deviation of the resampled image when the source pixels carry independent
        noise of standard deviation ``std`` (``(H_s, W_s[, C])``): sqrt(sum_i w_i^2 std_i^2)."""
        std = np.asarray(std, dtype=np.float64)
        flat = std[..., None] if std.ndim == 2 else std
        var = np.zeros(self.inside.shape + flat.shape[2:])
        for yi, xi, w in self.taps:
            var += (w * w)[..., None] * flat[yi, xi] ** 2
        var[~self.inside] = 0.0
        out = np.sqrt(var)
        return out[..., 0] if std.ndim == 2 else out
