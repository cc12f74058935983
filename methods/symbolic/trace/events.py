"""Events of the polynomial path tracer, from the device buffers to sparse coefficient matrices.

A path writes each of its contributions to one *event slot*: (ordered parameter key of the path,
value per channel); the host maps the keys to the monomials that occur (column indices).
A tile of ``n`` pixels x ``spp`` samples has ``spp × (N_max + T + 1)`` slots per pixel, most of
them empty or zero (occluded next-event estimation, paths that left the scene). The pass sums
them per pixel on the device (:mod:`methods.symbolic.trace.pixel_sums`); where it cannot (a key range
too wide for its key table), the slots are compacted on the device (``dr.compress``) and the rest
reaches the host, where the events of a pixel are summed into a row of a CSR matrix
(:meth:`EventBuffer.compact`, :func:`tile_matrices`; coefficients are ~1-3 % non-zero): memory is
that of the tile's events, never pixels x N_e.

The lanes of a tile come in two blocks, samples ``0 .. split - 1`` of every pixel, then the others
(:func:`lane_pixel`), so the events of each block are contiguous and the tile gives two
independent estimates ``A`` and ``B`` of the coefficients at no extra cost (:func:`tile_matrices`).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import scipy.sparse as sp

EMPTY = 0xFFFFFFFF   # key of an event slot that received no contribution (keys stay below it)


def event_slots(max_bounces: int, tail_bounces: int = 0, n_scales: int = 0, n_parts: int = 0) -> int:
    """Event slots of one path: the camera ray's, then one per vertex, two per vertex with unknown
    emitter scales (``n_scales > 0``: next-event estimation and the emitter hit may end on
    different emitters, each keyed by its own); each of these ``n_parts`` times when that many
    environments are summed into one and split again (``n_parts >= 2``)."""
    sites = 1 + (2 if n_scales else 1) * (int(max_bounces) + int(tail_bounces))
    return sites * max(1, int(n_parts))


def lane_pixel(lane, n: int, spp: int, split: int):
    """Tile pixel of each lane: ``n × split`` lanes (``split`` samples per pixel), then
    ``n × (spp - split)`` lanes (``split = spp``: one block)."""
    if split == spp:
        return lane // dr.opaque(mi.UInt32, spp)
    first = dr.opaque(mi.UInt32, n * split)
    in_b = lane >= first
    return dr.select(in_b, (lane - dr.select(in_b, first, 0)) // dr.opaque(mi.UInt32, spp - split),
                     lane // dr.opaque(mi.UInt32, split))


class EventBuffer:
    """Device buffers of a tile's events: slot ``k`` of lane ``l`` holds the ``k``-th
    (path key, value) of that lane's path; slots no contribution reached keep :data:`EMPTY`.

    ``capacity``: the lanes the buffers are sized for (default ``lanes``; the lanes beyond
    ``lanes`` stay empty). Dr.Jit's allocator rounds a buffer up to a power of two and hands a
    freed one again only to a request of that size, so a view's last, smaller tile would allocate
    its buffers beside its other tiles' cached ones; sized as they are, it takes them again."""

    def __init__(self, lanes: int, slots: int, n_channels: int, capacity: int | None = None):
        self.slots = slots
        size = max(int(lanes), int(capacity or 0)) * slots
        self.mono = dr.full(mi.UInt32, EMPTY, size)
        # values are read only where a key was stored with them: left uninitialised (a memset of
        # every slot cost 3 % of a 256-spp pass)
        self.values = [dr.empty(mi.Float, size) for _ in range(n_channels)]
        self._lane_base = dr.arange(mi.UInt32, lanes) * slots

    def nbytes(self) -> int:
        """Bytes of the buffers (as requested: the allocator rounds each up to a power of two)."""
        return dr.width(self.mono) * 4 * (1 + len(self.values))

    def store(self, slot, mono, value, active):
        """Write ``value`` (a Spectrum) with path key ``mono`` in slot ``slot`` of each active lane
        where it is not zero (an occluded next-event estimate, a miss: most of the slots)."""
        at = self._lane_base + slot
        active = active & dr.any(value != 0)
        dr.scatter(self.mono, mono, at, active)
        for c, v in enumerate(self.values):
            dr.scatter(v, value[c], at, active)

    def nonempty(self):
        """Slots that hold a contribution (a key; its value is not zero in some channel)."""
        return self.mono != EMPTY

    def compact(self, n: int, spp: int, split: int, *, samples: bool = False) -> tuple:
        """The non-empty, non-zero events, in lane order, on the host.

        Returns ``((rows, cols, vals), first_b)``: tile pixel (non-decreasing within a lane block,
        :func:`lane_pixel`), int32; ordered path key, int64; one float32 array of values per
        channel; and the index of the first event of the second block. With ``samples``, a third
        item: each event's sample number within its pixel's block (int32; 0 .. split - 1 in the
        first block, 0 .. spp - split - 1 in the second).
        """
        dr.eval(self.mono, self.values)                # the whole tile's paths: one kernel
        keep = self.nonempty()
        at = dr.compress(keep)                         # order-preserving: rows stay sorted
        if dr.width(at) == 0:                          # no light reached the tile: Dr.Jit cannot
            empty = np.zeros(0, np.int32)              # divide an empty array by a literal
            events = (empty, empty.astype(np.int64), [np.zeros(0, np.float32) for _ in self.values])
            return (events, 0, empty) if samples else (events, 0)
        lanes = at // dr.opaque(mi.UInt32, self.slots)
        rows = lane_pixel(lanes, n, spp, split).numpy().view(np.int32)
        cols = dr.gather(mi.UInt32, self.mono, at).numpy().astype(np.int64)
        vals = [dr.gather(mi.Float, v, at).numpy() for v in self.values]
        first_b = int(np.searchsorted(at.numpy(), n * split * self.slots))
        if not samples:
            return (rows, cols, vals), first_b
        lane = lanes.numpy().astype(np.int64)
        sample = np.empty(len(lane), np.int32)     # lane_pixel's layout: pixel-major within a block
        sample[:first_b] = lane[:first_b] % split
        sample[first_b:] = (lane[first_b:] - n * split) % (spp - split)
        return (rows, cols, vals), first_b, sample


def csr(rows, cols, vals, shape, weight: float = 1.0) -> list:
    """Canonical ``csr_matrix`` (sorted indices, duplicates summed, times ``weight``), one per
    entry of ``vals`` (channels), from events whose ``rows`` are non-decreasing.

    The channels share their sparsity, so the within-row sort runs once: scipy sorts the event
    numbers as data along with the columns, which gives the permutation for every channel. It
    sorts ``cols`` itself (scipy keeps the array it is given): pass a copy to use them again.
    """
    n, m = shape[0], len(cols)
    if m == 0:
        return [sp.csr_matrix(shape) for _ in vals]
    indptr = np.searchsorted(rows, np.arange(n + 1))
    perm = sp.csr_matrix((np.arange(m, dtype=np.float64), cols, indptr), shape=shape)
    perm.sort_indices()
    order, cols = perm.data.astype(np.intp), perm.indices
    first = np.empty(m, bool)                  # first event of each (row, column)
    first[0] = True
    first[1:] = (cols[1:] != cols[:-1]) | (rows[1:] != rows[:-1])
    starts = np.flatnonzero(first)
    indptr = np.searchsorted(rows[starts], np.arange(n + 1))
    out = []
    for v in vals:
        data = np.add.reduceat(v[order], starts, dtype=np.float64)
        if weight != 1.0:
            data *= weight
        mat = sp.csr_matrix((data, cols[starts], indptr), shape=shape)
        mat.has_canonical_format = True
        out.append(mat)
    return out


def tile_matrices(events: tuple, first_b: int, shape: tuple[int, int], spp: int, split: int,
                  sample: np.ndarray | None = None) -> tuple:
    """A tile's events (values already divided by ``spp``) as sparse matrices of ``shape``:
    ``(Γ,)`` when ``split = spp``, else ``(A, B)``, and with ``sample`` (each event's sample
    number in its block, :meth:`EventBuffer.compact`) ``(A, B, A₁, B₁)``.

    ``A`` holds the ``split`` first samples of each pixel, ``B`` the others, each reweighted to
    a full estimate (:func:`halves_mean` is the estimate from all samples).
    ``A₁`` holds the first half of ``A``'s samples, ``B₁`` that of ``B``'s (``spp`` a multiple of
    4, ``split = spp / 2``): the four quarters are ``A₁``, ``2A - A₁``, ``B₁``, ``2B - B₁``.
    """
    rows, cols, vals = events
    if split == spp:
        return (csr(rows, cols, vals, shape),)
    in_a, in_b = slice(0, first_b), slice(first_b, len(rows))
    firsts = ()
    if sample is not None:     # before A and B: csr sorts the columns of the slices it gets in place
        if spp % 4 or 2 * split != spp:
            raise ValueError(f"quarters need spp a multiple of 4 and split = spp / 2 (spp={spp}, split={split})")
        quarter = spp // 4
        keeps = [np.flatnonzero(sample[block] < quarter) + block.start for block in (in_a, in_b)]
        firsts = tuple(csr(rows[k], cols[k], [v[k] for v in vals], shape, weight=spp / quarter) for k in keeps)
    A = csr(rows[in_a], cols[in_a], [v[in_a] for v in vals], shape, weight=spp / split)
    B = csr(rows[in_b], cols[in_b], [v[in_b] for v in vals], shape, weight=spp / (spp - split))
    return (A, B) + firsts


def halves_mean(A: list, B: list, spp: int, split: int) -> list:
    """``Γ``, the estimate from all ``spp`` samples: the sample-count-weighted mean of the half
    estimates ``A`` (``split`` samples) and ``B`` (the others), per channel."""
    wa, wb = split / spp, (spp - split) / spp
    return [(a + b) * 0.5 if wa == wb else a * wa + b * wb for a, b in zip(A, B)]


def reindex_columns(mats: tuple, positions: np.ndarray, n_cols: int) -> tuple:
    """Per-channel matrix lists ``mats`` with column ``j`` moved to ``positions[j]`` of ``n_cols``
    (increasing ``positions``: the indices stay sorted, the format canonical)."""
    if len(positions) == n_cols:                # every column kept where it is (a view of one tile)
        return mats
    def move(m):
        out = sp.csr_matrix((m.data, positions[m.indices], m.indptr), shape=(m.shape[0], n_cols))
        out.has_canonical_format = True
        return out
    return tuple([move(m) for m in ms] for ms in mats)


def stack_tiles(tiles: list[tuple], n_out: int, n_channels: int, n_cols: int) -> tuple:
    """The ``n_out`` per-channel matrix lists of consecutive tiles, stacked by rows."""
    if not tiles:
        return tuple([sp.csr_matrix((0, n_cols)) for _ in range(n_channels)] for _ in range(n_out))
    if len(tiles) == 1:
        return tiles[0]
    return tuple([sp.vstack([t[k][c] for t in tiles], format="csr") for c in range(n_channels)]
                 for k in range(n_out))
