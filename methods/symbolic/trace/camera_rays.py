"""Film, sampler and camera-ray helpers of the polynomial path tracer (no estimator logic here).

:mod:`methods.symbolic.trace.integrator` renders a view as tiles of pixels, one Dr.Jit kernel each:
these helpers pick the pixels of a tile, seed its sampler and shoot its camera rays, as
Mitsuba's ``ADIntegrator.sample_rays`` does for a whole film.
"""
from __future__ import annotations

import warnings

import drjit as dr
import mitsuba as mi
import numpy as np

from framework.errors import ConfigError
from framework.render.arrays import device_array


def mis_weight(pdf_a, pdf_b):
    """Power heuristic ``pdf_a² / (pdf_a² + pdf_b²)`` (0 where ``pdf_a = 0``), as Mitsuba's ``path``."""
    a2 = dr.square(pdf_a)
    return dr.select(pdf_a > 0, a2 / dr.fma(pdf_b, pdf_b, a2), 0)


def pixel_window(film, pixel_range) -> tuple[int, int]:
    """``[start, stop)`` of ``pixel_range`` (default: every pixel) in row-major order of the
    film's crop window, checked; warns when the film's filter is not the assumed box filter."""
    if not film.rfilter().is_box_filter():
        warnings.warn("coefficients() assumes a box pixel filter; the film's filter is "
                      f"{film.rfilter().class_().name()} (samples stay in their pixel)")
    W, H = (int(v) for v in film.crop_size())
    n_pix = W * H
    start, stop = (0, n_pix) if pixel_range is None else (int(pixel_range[0]), int(pixel_range[1]))
    if not 0 <= start <= stop <= n_pix:
        raise ConfigError(f"pixel_range=({start}, {stop}) outside [0, {n_pix}]")
    return start, stop


def tile_sampler(sensor, spp: int, seed: int, start: int, n: int):
    """The sensor's sampler, cloned and seeded for the ``n`` pixels x ``spp`` lanes of the tile
    starting at pixel ``start``: one wavefront, so the tile is one kernel."""
    sampler = sensor.sampler().clone()
    sampler.set_sample_count(spp)
    sampler.set_samples_per_wavefront(spp)
    sampler.seed(_tile_seed(seed, start), n * spp)
    return sampler


def _tile_seed(seed: int, start: int) -> int:
    """Seed of the tile starting at pixel ``start``: ``seed`` itself for the first tile, so that a
    single-tile render does not depend on the tiling; a 64-bit mix of both for the others."""
    if start == 0:
        return int(seed) & 0xFFFFFFFF
    x = (int(seed) * 0x9E3779B97F4A7C15 + int(start) * 0xBF58476D1CE4E5B9 + 1) & (2 ** 64 - 1)
    x ^= x >> 31
    x = (x * 0x94D049BB133111EB) & (2 ** 64 - 1)
    x ^= x >> 29
    return x & 0xFFFFFFFF


class TileFootprint:
    """A :class:`framework.scene.undistort.Footprint` of a tile's pixels as Dr.Jit arrays, for
    :func:`camera_rays`: each sample picks one of a pixel's ``K`` source pixels with probability
    ``|w_k| / sum |w|`` and weighs its radiance by ``sign(w_k) sum |w|`` (an unbiased estimate of
    ``sum_k w_k L_k`` with Keys' negative weights too).

    Parameters
    ----------
    footprint : Footprint
        Of the pixels ``[start, start + N)``.
    start : int
        The tile's first pixel (row-major in the crop window).
    """

    def __init__(self, footprint, start: int):
        w = np.asarray(footprint.weight, np.float64)
        self.K = w.shape[1]
        total = np.abs(w).sum(axis=1, keepdims=True)
        cum = np.cumsum(np.abs(w), axis=1) / total
        cum[:, -1] = 1.0                                  # round-off must not leave u above the last
        self.start = int(start)
        self.cum = device_array(mi.Float, cum.ravel())
        self.scale = device_array(mi.Float, (np.sign(w) * total).ravel())
        p, j = np.asarray(footprint.position), np.asarray(footprint.jacobian)
        self.position = [device_array(mi.Float, p[..., a].ravel()) for a in range(2)]
        self.jacobian = [device_array(mi.Float, j[..., a, b].ravel()) for a in range(2) for b in range(2)]

    def sample(self, local, u, box):
        """``(film position, weight)`` of lanes of the tile's pixels ``local`` (from 0), ``u`` and
        ``box`` uniform samples (the source pixel's choice and a point in its box)."""
        chosen = mi.UInt32(self.K - 1)
        for k in reversed(range(self.K - 1)):          # the first k whose cumulative weight is above u
            c = dr.gather(mi.Float, self.cum, local * self.K + k)
            chosen = dr.select(u < c, k, chosen)
        at = local * self.K + chosen
        d = box - 0.5
        j = [dr.gather(mi.Float, a, local) for a in self.jacobian]
        x = dr.gather(mi.Float, self.position[0], at) + j[0] * d.x + j[1] * d.y
        y = dr.gather(mi.Float, self.position[1], at) + j[2] * d.x + j[3] * d.y
        return mi.Vector2f(x, y), dr.gather(mi.Float, self.scale, at)


def camera_rays(sensor, sampler, pix, footprint: TileFootprint | None = None):
    """``(ray, weight)`` through pixels ``pix`` (row-major in the crop window), one per lane.

    As ``ADIntegrator.sample_rays`` with a box filter and no border: the position is uniform
    inside the pixel, so a sample never contributes to a neighbour. Draws from ``sampler`` in
    Mitsuba's order: position, aperture (if needed), time (if the shutter is open), wavelength
    (spectral variants). With a ``footprint`` (a resampled photograph's pixels) the position is
    drawn from it instead (one more draw, first: the source pixel) and ``weight`` carries its
    sign and scale.
    """
    film = sensor.film()
    W = int(film.crop_size()[0])
    crop_size = mi.ScalarVector2f(film.crop_size())
    crop_offset = mi.ScalarVector2f(film.crop_offset())
    share = 1.0                         # the footprint's sign and scale of the source pixel drawn
    if footprint is None:
        pos = mi.Vector2i()
        pos.y = mi.Int32(pix // dr.opaque(mi.UInt32, W))
        pos.x = mi.Int32(pix) - pos.y * dr.opaque(mi.Int32, W)
        pos += mi.Vector2i(film.crop_offset())
        pos_f = mi.Vector2f(pos) + sampler.next_2d()
    else:
        u = sampler.next_1d()
        pos_f, share = footprint.sample(pix - dr.opaque(mi.UInt32, footprint.start), u, sampler.next_2d())
    scale = dr.rcp(crop_size)
    offset = -crop_offset * scale
    pos_adjusted = dr.fma(pos_f, scale, offset)
    aperture = sampler.next_2d() if sensor.needs_aperture_sample() else mi.Point2f(0.5)
    time = sensor.shutter_open()
    if sensor.shutter_open_time() > 0:
        time += sampler.next_1d() * sensor.shutter_open_time()
    wavelength_sample = sampler.next_1d() if mi.is_spectral else 0.0
    ray, weight = sensor.sample_ray_differential(time=time, sample1=wavelength_sample,
                                                 sample2=pos_adjusted, sample3=aperture)
    return ray, weight * share
