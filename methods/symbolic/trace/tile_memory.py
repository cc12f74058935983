"""The device memory of one tile of the polynomial pass, as Dr.Jit allocates it.

Dr.Jit's allocator rounds every buffer up to the next power of two and keeps freed buffers for
reuse by one of the same size (drjit-core's ``jit_malloc``; both backends, ``llvm_*`` and
``cuda_*``). A tile of ``n`` pixels x ``spp`` samples with ``S`` event slots a sample and ``C``
channels holds at its peak, each buffer rounded so (``P(x)``: the power of two at or above ``x``
bytes, ``E = n · spp · S`` the tile's event slots):

* its events: a key and ``C`` values a slot, ``(1 + C) · P(4 E)``
  (:class:`~methods.symbolic.trace.events.EventBuffer`);
* the slots that hold one, compacted (``dr.compress`` allocates for every slot): ``P(4 E)``;
* with a key table (:mod:`~methods.symbolic.trace.pixel_sums`), the events' columns (a buffer of
  every slot too, ``P(4 E)``) and the per-pixel sums' work arrays: their bitmap, ranks and summed
  cells, at most :func:`work_budget` ``= P(4 E) / 2`` a chunk of pixels; without one, one
  gathered event array at a time for the host, ``P(4 E)``
  (:meth:`~methods.symbolic.trace.events.EventBuffer.compact`); the work and gathered arrays
  counted twice, since their sizes vary from tile to tile and the allocator keeps one freed
  buffer of each size;
* each sample's lane offset ``P(4 n spp)``, each pixel's event counts ``2 P(8 n)`` and the path
  keys' table ``2 P(4 K)`` (``K`` the key range, :func:`key_table_bytes`).

Not modelled: the bitmap of a tile with thousands of monomials (a street of many materials), two
bits a (pixel, monomial) cell, which its chunks of at most
:data:`~methods.symbolic.trace.pixel_sums.CHUNK_CELLS` cells keep below 192 MiB (three arrays of
32 MiB rounded to 64) but not within the work budget (cut to it, the chunks made such a pass 48 %
slower); with the 253-2,500 monomials of the bundled scenes' views it fits.

A view's tiles hold the same number of lanes (its last tile's buffers are sized as the others',
:class:`~methods.symbolic.trace.events.EventBuffer`), so the allocator reuses them from tile to
tile and from view to view. Measured with Dr.Jit's allocation watermark
(:func:`framework.render.jit_timing.device_peak`), the model bounds the peak of every tested
configuration (``tests/methods/test_tile_memory.py``; bench section 1 reports it).
"""
from __future__ import annotations

from methods.symbolic.trace.monomial_codes import TABLE_KEYS


def allocated(nbytes: int) -> int:
    """Bytes Dr.Jit's allocator reserves for a buffer of ``nbytes``: the next power of two (0 for none)."""
    nbytes = int(nbytes)
    return 0 if nbytes <= 0 else 1 << (nbytes - 1).bit_length()


def work_budget(lanes: int, slots: int) -> int:
    """Bytes the per-pixel sums of a tile may allocate for one chunk of its pixels (bitmap, ranks,
    summed cells, row starts): half of one event buffer of the tile, ``P(4 lanes slots) / 2``."""
    return allocated(4 * int(lanes) * int(slots)) // 2


def key_table_bytes(key_span: int) -> int:
    """The path keys' table on the device (the keys that occur, then key -> column): ``2 P(4 K)``,
    none where the key range ``K`` exceeds :data:`~methods.symbolic.trace.monomial_codes.TABLE_KEYS`
    (the tile is summed on the host)."""
    return 2 * allocated(4 * int(key_span)) if key_span <= TABLE_KEYS else 0


def tile_device_bytes(pixels: int, spp: int, slots: int, n_channels: int, key_span: int) -> int:
    """Peak device bytes of a tile of ``pixels`` pixels x ``spp`` samples, ``slots`` event slots a
    sample, ``n_channels`` values a slot and path keys below ``key_span`` (module docstring)."""
    lanes = int(pixels) * int(spp)
    events = allocated(4 * lanes * int(slots))                 # one event buffer (or the compacted slots)
    if key_span <= TABLE_KEYS:       # the events' columns, and the sums' work arrays
        extra = events + 2 * work_budget(lanes, slots)
    else:                            # the gathered arrays for the host
        extra = 2 * events
    return ((2 + int(n_channels)) * events + extra + allocated(4 * lanes) + 2 * allocated(8 * int(pixels))
            + key_table_bytes(key_span))
