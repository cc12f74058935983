"""The tiling API of the polynomial path tracer: a view's pixels traced tile by tile into sparse
coefficient matrices (:class:`CoefficientTiles`, a base of
:class:`~methods.symbolic.trace.integrator.PolynomialPathMixin`)."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from framework.errors import ConfigError
from methods.symbolic.trace.camera_rays import TileFootprint, camera_rays, pixel_window, tile_sampler
from methods.symbolic.trace.events import (EventBuffer, halves_mean, lane_pixel, reindex_columns, stack_tiles,
                                          tile_matrices)
from methods.symbolic.trace.monomial_codes import emitter_columns, merge_codes, monomial_columns
from methods.symbolic.trace.pixel_sums import pixel_sums


class CoefficientTiles:
    """``coefficients*``: one view's polynomial coefficients (eq. 8), traced ``tile_pixels`` pixels
    at a time by the path loop ``_trace`` of the class it is mixed into.

    Each tile's events are summed per pixel and monomial on the device
    (:func:`~methods.symbolic.trace.pixel_sums.pixel_sums`); where the key range is too wide for its key
    table, or with :attr:`device_sums` False, they are compacted and summed on the host
    (:meth:`~methods.symbolic.trace.events.EventBuffer.compact`,
    :func:`~methods.symbolic.trace.events.tile_matrices`).
    """

    #: sum each tile's events on the device (False: on the host; both give the same coefficients)
    device_sums = True

    def coefficients(self, scene: mi.Scene, sensor=0, *, spp: int, seed: int = 0,
                     pixel_range: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(codes, γ)``: dense ``(stop - start, len(codes), C)`` float32 coefficients (eq. 8) of
        one view's pixels over the monomial ``codes`` that occur.

        Same arguments as :meth:`coefficients_sparse`, whose result this densifies (for tests and
        small images; the inversion keeps the sparse form).
        """
        codes, mats = self.coefficients_sparse(scene, sensor, spp=spp, seed=seed, pixel_range=pixel_range)
        return codes, np.stack([m.toarray() for m in mats], axis=-1).astype(np.float32)

    def coefficients_sparse(self, scene: mi.Scene, sensor=0, *, spp: int, seed: int = 0,
                            pixel_range: tuple[int, int] | None = None, footprint=None) -> tuple[np.ndarray, list]:
        """Polynomial coefficients ``γ`` (eq. 8) of the pixels of one view, one sparse matrix per channel.

        Parameters
        ----------
        scene : mi.Scene
            The scene whose shapes were given to :meth:`configure`.
        sensor : int or mi.Sensor
            Sensor (index into ``scene.sensors()`` or the sensor itself).
        spp : int
            Samples per pixel (>= 1).
        seed : int
            Sampler seed; tiles after the first derive their own seed from it.
        pixel_range : (int, int), optional
            Pixels ``[start, stop)`` in row-major order of the film's crop window; default all.
        footprint : framework.scene.undistort.Resampling, optional
            The view's photographs were resampled from another camera (a distorted lens): each
            pixel integrates over the source pixels its resampled value weighs
            (:meth:`~framework.scene.undistort.Resampling.footprint`), so the polynomials carry
            the interpolation's blur. Default: each pixel's own box.

        Returns
        -------
        (numpy.ndarray, list of scipy.sparse.csr_matrix)
            The sorted multiset codes of the monomials that occur (always 0, the constant;
            :class:`~methods.symbolic.system.basis.MonomialBasis`), and ``C`` matrices of shape
            ``(stop - start, len(codes))``, float64, canonical (sorted indices, no duplicates).
        """
        codes, gamma = self._tiled(scene, sensor, spp, seed, pixel_range, halves=False, footprint=footprint)
        return codes, gamma

    def coefficients_halves(self, scene: mi.Scene, sensor=0, *, spp: int, seed: int = 0,
                            pixel_range: tuple[int, int] | None = None, footprint=None,
                            quarters: bool = False, mean: bool = True) -> tuple:
        """``(codes, A, B, Γ)``: two independent estimates of the coefficients and their mean, from
        one render, over the monomial ``codes`` that occur.

        ``A`` uses the samples ``0 .. spp//2 - 1`` of every pixel, ``B`` the others, ``Γ`` all
        of them (``Γ = (spp//2 · A + (spp - spp//2) · B) / spp``; the lanes are laid out in two
        sample blocks, so Γ is not :meth:`coefficients_sparse`'s result at the same seed, only
        an estimate of the same coefficients). The sampler is ``independent``, so ``A`` and ``B`` are independent and
        ``E[AᵀB] = E[A]ᵀE[B]`` (:meth:`GramSystem.accumulate_sparse`). Arguments as
        :meth:`coefficients_sparse`, with ``spp >= 2``; with ``quarters`` (``spp`` a multiple of
        4) also ``A₁`` and ``B₁``, the estimates from the first half of ``A``'s and of ``B``'s
        samples: ``(codes, A, B, Γ, A₁, B₁)``, four independent quarter estimates
        ``A₁, 2A - A₁, B₁, 2B - B₁`` of the same render
        (:func:`~methods.symbolic.trace.events.tile_matrices`). With ``mean=False``, Γ is None (it
        costs a sum of the two halves that a caller who keeps ``A`` and ``B`` can skip).
        """
        if int(spp) < 2:
            raise ConfigError(f"spp={spp}: two independent halves need spp >= 2")
        if quarters and int(spp) % 4:
            raise ConfigError(f"spp={spp}: four independent quarters need spp a multiple of 4")
        codes, A, B, *firsts = self._tiled(scene, sensor, spp, seed, pixel_range, halves=True, footprint=footprint,
                                           quarters=quarters)
        return (codes, A, B, halves_mean(A, B, int(spp), int(spp) // 2) if mean else None, *firsts)

    def _tiled(self, scene, sensor, spp, seed, pixel_range, halves: bool, footprint=None,
               quarters: bool = False) -> tuple:
        """Checks, then the tiles of ``tile_pixels`` pixels over their merged codes, stacked:
        ``(codes, Γ)``, ``(codes, A, B)`` or ``(codes, A, B, A₁, B₁)``."""
        self._check()
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        if int(spp) < 1:
            raise ConfigError(f"spp={spp}: must be >= 1")
        spp = int(spp)
        start, stop = pixel_window(sensor.film(), pixel_range)
        if footprint is not None:
            _check_footprint(footprint, sensor.film())
        split = spp // 2 if halves else spp
        tiles = [self._tile(scene, sensor, spp, seed, t0, min(stop, t0 + self.tile_pixels), split, footprint,
                            quarters)
                 for t0 in range(start, stop, self.tile_pixels)]
        codes = merge_codes([0], *(codes for codes, _ in tiles))
        mats = [reindex_columns(t, np.searchsorted(codes, c), len(codes)) for c, t in tiles]
        return (codes,) + stack_tiles(mats, 4 if quarters else 2 if halves else 1, self.n_channels, len(codes))

    def _tile(self, scene, sensor, spp, seed, start, stop, split, footprint=None, quarters=False) -> tuple:
        """Trace the pixels ``[start, stop)``, ``spp`` samples each, as one kernel: the codes of
        their monomials and their matrices ``(Γ,)``, or ``(A, B)`` with the first
        ``split < spp`` samples of each pixel in ``A`` (and ``A₁``, ``B₁`` with ``quarters``)."""
        n = stop - start
        if n * spp >= 2 ** 32:
            raise ConfigError(f"tile of {n} pixels x {spp} spp too large for 32-bit indices: lower tile_pixels")
        sampler = tile_sampler(sensor, spp, seed, start, n)
        pix = lane_pixel(dr.arange(mi.UInt32, n * spp), n, spp, split) + dr.opaque(mi.UInt32, start)
        tile_footprint = None if footprint is None else TileFootprint(footprint.footprint(start, stop), start)
        ray, weight = camera_rays(sensor, sampler, pix, tile_footprint)
        # sized as the view's full tile: every tile then reuses the same device buffers
        width, height = (int(v) for v in sensor.film().crop_size())
        capacity = min(self.tile_pixels, width * height) * spp
        events = EventBuffer(n * spp, self.event_slots(), self.n_channels, capacity=capacity)
        β = mi.Spectrum(weight) * dr.opaque(mi.Float, 1.0 / spp)      # box filter: 1/spp per sample
        self._trace(scene, sampler, mi.Ray3f(ray), β, mi.Bool(True), events.store)
        if self.device_sums:
            summed = pixel_sums(events, n=n, spp=spp, split=split, quarters=quarters, span=self._key_span(),
                                columns=self._columns, tile_bytes=events.nbytes() // capacity * self.tile_pixels * spp)
            if summed is not None:
                return summed
        (rows, keys, vals), first_b, *sample = events.compact(n, spp, split, samples=quarters)
        codes, cols = self._columns(keys)
        return codes, tile_matrices((rows, cols, vals), first_b, (n, len(codes)), spp, split, *sample)

    def _key_span(self) -> int:
        """The ordered path keys lie below this (the emitter's group above the path's digits)."""
        return (self.n_params + 1) ** self.max_bounces * (self.n_scales + 1)

    def _columns(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(codes, cols)`` of ordered path keys: the ordered keys of one monomial differ by the
        order of its parameters, sorted out here; with unknown emitter scales the emitter's
        group is one more variable."""
        if self.n_scales:
            return emitter_columns(keys, self.n_params, self.max_bounces, self.n_scales)
        return monomial_columns(keys, self.n_params, self.max_bounces)


def _check_footprint(footprint, film) -> None:
    """The footprint's target image must be the film, whole (its pixels are numbered the same)."""
    size = (int(footprint.target.width), int(footprint.target.height))
    if size != tuple(int(v) for v in film.size()):
        raise ConfigError(f"footprint of a {size[0]}x{size[1]} camera for a film of "
                          f"{film.size()[0]}x{film.size()[1]}: give the view's own Resampling")
    if any(int(v) for v in film.crop_offset()) or tuple(int(v) for v in film.crop_size()) != size:
        raise ConfigError("a footprint (resampled photographs) needs the whole film: no crop window")
