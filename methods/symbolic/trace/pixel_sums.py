"""A tile's events summed per pixel and monomial where they were traced (Dr.Jit, ``llvm_*`` and
``cuda_*`` alike): what reaches the host is the tile's coefficients, never its events.

A tile of ``n`` pixels x ``spp`` samples writes ``spp × slots`` event slots per pixel
(:class:`~methods.symbolic.trace.events.EventBuffer`); a pixel's coefficients over the monomials that
occur are 1-6 % as many numbers. On a GPU, copying the events out and summing them with numpy
was 95 % of the pass; here the device does it, in three steps and one small host step:

1. the slots holding an event are compacted (``dr.compress``, order kept); the ordered path keys
   that occur are marked in a table over the key range and compacted: the host receives the
   distinct keys (a few hundred), maps them to monomial columns
   (:func:`~methods.symbolic.trace.monomial_codes.monomial_columns`, or ``emitter_columns`` with unknown emitter
   scales) and sends back the key -> column table;
2. each event gets its row ``block · n + pixel`` (the blocks are the sample halves ``A``, ``B``;
   with ``quarters`` the first halves ``A₁``, ``B₁`` are their events again, two blocks on) and
   its cell ``row · N_e,tile + column``; the occupied cells are marked in a bitmap (an atomic OR)
   whose per-word population counts, prefix-summed, give each occupied cell its rank: its index
   in CSR order. No sort: the events of a row are already contiguous (the lanes' layout);
3. one lane per row of ``A`` (and ``B``) walks its events in order and adds each to its cell's
   rank (float64): each cell is summed by one lane in one order, so the same seed gives the same
   bits on any backend and thread count, where atomic adds from many lanes would round in a
   scheduling-dependent order. The columns, the sums and each row's first rank (``indptr``) are
   copied out: each block is a canonical CSR matrix as it arrives.

Memory on the device is that of the events plus two bits per (row, monomial) cell (the bitmap and
its ranks); a tile whose cells exceed :data:`CHUNK_CELLS` is summed a chunk of its pixels at a
time, each chunk marking and summing only its pixels' events. Key ranges above
:data:`~methods.symbolic.trace.monomial_codes.TABLE_KEYS` (hundreds of parameters) have no key table:
:func:`pixel_sums` returns None and the caller sums on the host
(:func:`~methods.symbolic.trace.events.tile_matrices`). Both sum the float32 values in float64, in
another order: they agree to float32 rounding (``tests/methods/test_polynomial_integrator.py``).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import scipy.sparse as sp

from methods.symbolic.trace.events import lane_pixel
from methods.symbolic.trace.monomial_codes import TABLE_KEYS


def pixel_sums(events, *, n: int, spp: int, split: int, quarters: bool, span: int, columns) -> tuple | None:
    """``(codes, matrices)`` of a traced tile, or None when its key range has no table.

    Parameters
    ----------
    events : methods.symbolic.trace.events.EventBuffer
        The tile's event slots, traced.
    n, spp, split : int
        Pixels, samples per pixel, samples of the first block (``split = spp``: one block).
    quarters : bool
        Also the first half of each block's samples (``spp`` a multiple of 4, ``split = spp / 2``).
    span : int
        The ordered path keys lie in ``[0, span)``.
    columns : callable
        ``columns(distinct_keys) -> (codes, cols)``: the monomial codes occurring among the sorted
        distinct keys and each key's column.

    Returns
    -------
    tuple or None
        None when the key range has no table or the cells overflow 32 bits (the caller sums on the
        host); else ``(codes, mats)``, ``mats`` as :func:`~methods.symbolic.trace.events.tile_matrices`
        returns them:
        ``(Γ,)``, ``(A, B)`` or ``(A, B, A₁, B₁)``, each a list of ``C`` canonical float64
        ``csr_matrix`` of shape ``(n, len(codes))``.
    """
    if span > TABLE_KEYS:
        return None
    at = dr.compress(events.nonempty())            # the slots holding an event, in order
    halves = split < spp
    blocks = (4 if quarters else 2) if halves else 1
    if dr.width(at) == 0:                          # no light reached the tile (and Dr.Jit cannot
        codes, summed = np.zeros(1, np.int64), _no_sums(blocks * n, len(events.values))   # divide an empty array)
        return codes, _matrices(summed, n, 1, spp, split, blocks)
    codes, table = _key_table(dr.gather(mi.UInt32, events.mono, at), span, columns)
    if blocks * len(codes) >= 2 ** 32:              # a chunk's cells are 32-bit (never seen: 2³² monomials)
        return None
    tile = _Tile(events, at, table, n=n, spp=spp, split=split, n_cols=len(codes), blocks=blocks)
    m = _chunk_pixels(n, len(codes), blocks)
    chunks = [_matrices(tile.sums(p0, min(m, n - p0)), min(m, n - p0), len(codes), spp, split, blocks)
              for p0 in range(0, n, m)]
    return codes, chunks[0] if len(chunks) == 1 else _stacked(chunks)


# The cells' bitmap holds a bit per (row, tile monomial) and its ranks a 32-bit count per 32 bits:
# 2 bits per cell, which ``method.memory_mb`` (it sizes the events) does not count, and a street of
# many materials makes large (a 70-material view of 40,000 pixels has 19,000 monomials: 370 MiB).
# A tile's pixels are summed in chunks of at most this many cells (64 MiB of bitmap and ranks),
# each over the events of its pixels.
CHUNK_CELLS = 2 ** 28


def _chunk_pixels(n: int, n_cols: int, blocks: int) -> int:
    """Pixels per chunk: the whole tile when its cells fit in :data:`CHUNK_CELLS`."""
    return max(1, min(n, CHUNK_CELLS // (blocks * n_cols)))


def _stacked(chunks: list) -> tuple:
    """The chunks' matrices of each block and channel stacked by rows (pixels in order)."""
    return tuple([sp.vstack([c[k][ch] for c in chunks], format="csr") for ch in range(len(chunks[0][k]))]
                 for k in range(len(chunks[0])))


def _key_table(mono, span: int, columns) -> tuple[np.ndarray, object]:
    """The codes of the events' keys ``mono`` and the device table key -> column (step 1)."""
    seen = dr.zeros(mi.UInt32, span)
    dr.scatter(seen, mi.UInt32(1), mono)
    distinct = dr.compress(seen != 0)              # sorted: the keys that occur
    codes, cols = columns(distinct.numpy().astype(np.int64))
    table = dr.zeros(mi.UInt32, span)
    dr.scatter(table, mi.UInt32(cols.astype(np.uint32)), distinct)
    return np.asarray(codes, np.int64), table


def _no_sums(rows: int, n_channels: int) -> tuple:
    """:meth:`_Tile.sums` of a tile without events."""
    return np.zeros(rows + 1, np.int32), np.zeros(0, np.int32), [np.zeros(0) for _ in range(n_channels)]


class _Tile:
    """A tile's events (``at``: the slots that hold one), their pixels, blocks and columns
    (step 2), summed a chunk of pixels at a time (:meth:`sums`).

    A chunk of ``m`` pixels from ``p0`` has rows ``b · m + (pixel - p0)``, block-major; the
    summing rows are those of the blocks A (and B), whose events are contiguous in slot order;
    with quarters, rows ``(b + 2) · m + ...`` hold again the events of the first half of block
    ``b``'s samples (``A₁``, ``B₁``).
    """

    def __init__(self, events, at, table, *, n: int, spp: int, split: int, n_cols: int, blocks: int):
        self.events, self.at, self.n, self.n_cols, self.blocks = events, at, n, n_cols, blocks
        self.slots, self.spp, self.split = events.slots, spp, split
        self.pixel, self.block, self.first_quarter = _lane_cells(at // dr.opaque(mi.UInt32, events.slots),
                                                                 n, spp, split, blocks)
        self.col = dr.gather(mi.UInt32, table, dr.gather(mi.UInt32, events.mono, at))
        # each summing row's event count and first event in ``at`` (exclusive prefix sum), tile-wide
        self.events_per_row = dr.zeros(mi.UInt32, n * min(blocks, 2))
        dr.scatter_add(self.events_per_row, mi.UInt32(1), self.block * dr.opaque(mi.UInt32, n) + self.pixel)
        self.first_event = dr.prefix_sum(self.events_per_row)

    def sums(self, p0: int, m: int) -> tuple:
        """``(indptr, cols, [values per channel])`` of pixels ``p0 .. p0 + m - 1``: the occupied
        (row, column) cells in CSR form over the chunk's ``blocks · m`` rows: row ``k``'s cells
        are ``indptr[k] .. indptr[k + 1] - 1``, with their columns (increasing) and summed
        values (step 3)."""
        first, size = dr.opaque(mi.UInt32, p0), dr.opaque(mi.UInt32, m)
        inside = (self.pixel >= first) & (self.pixel < first + size)       # unsigned: no wrap below p0
        cell = (self.block * size + self.pixel - first) * dr.opaque(mi.UInt32, self.n_cols) + self.col
        shift = dr.opaque(mi.UInt32, 2 * m * self.n_cols)                  # to the rows of A₁, B₁
        words = dr.zeros(mi.UInt32, -(-self.blocks * m * self.n_cols // 32))
        _mark(words, cell, inside)
        if self.blocks == 4:
            _mark(words, cell + shift, inside & self.first_quarter)
        rank = _Ranks(words)
        index = np.int32 if rank.total < 2 ** 31 else np.int64     # scipy's index type for this size
        cols = dr.zeros(mi.UInt32, rank.total)
        sums = [dr.zeros(mi.Float64, rank.total) for _ in self.events.values]
        self._row_sums(p0, m, cell, shift, rank, cols, sums)
        starts = rank(dr.arange(mi.UInt32, self.blocks * m) * dr.opaque(mi.UInt32, self.n_cols), True)   # rows' first
        dr.eval(cols, sums, starts)
        indptr = np.append(starts.numpy().astype(index), index(rank.total))
        return indptr, cols.numpy().astype(index), [v.numpy() for v in sums]

    def _row_sums(self, p0: int, m: int, cell, shift, rank, cols, sums) -> None:
        """Each occupied cell's column and sum, written at its rank: one lane per summing row of
        the chunk walks that row's events in slot order, so each cell is summed by one lane in
        one order: the same seed gives the same bits on any backend and thread count (atomic adds
        from many lanes sum in a scheduling-dependent order)."""
        n, slots, size = self.n, dr.opaque(mi.UInt32, self.slots), dr.opaque(mi.UInt32, m)
        local = dr.arange(mi.UInt32, m * min(self.blocks, 2))
        in_b = local >= size
        pixel = dr.opaque(mi.UInt32, p0) + local - dr.select(in_b, size, 0)
        r = dr.select(in_b, dr.opaque(mi.UInt32, n), 0) + pixel             # the tile-wide summing row
        count, first_event = dr.gather(mi.UInt32, self.events_per_row, r), dr.gather(mi.UInt32, self.first_event, r)
        per_pixel = dr.select(in_b, dr.opaque(mi.UInt32, self.spp - self.split), dr.opaque(mi.UInt32, self.split))
        # block B's pixel p starts at lane n·split + p·(spp - split)
        first_slot = (dr.select(in_b, dr.opaque(mi.UInt32, n * self.split), 0) + pixel * per_pixel) * slots
        quarter = dr.opaque(mi.UInt32, (self.spp // 4) * self.slots)
        n_cols = dr.opaque(mi.UInt32, self.n_cols)

        def add(c, values, active):
            # a lane's cells are its row's alone: no two lanes of a packet reach the same one
            where = rank(c, active)
            dr.scatter(cols, c % n_cols, where, active)
            for total, v in zip(sums, values):
                dr.scatter_add(total, mi.Float64(v), where, active, mode=dr.ReduceMode.NoConflicts)

        def body(j):
            e = first_event + j
            slot = dr.gather(mi.UInt32, self.at, e)
            c = dr.gather(mi.UInt32, cell, e)
            values = [dr.gather(mi.Float, v, slot) for v in self.events.values]
            add(c, values, True)
            if self.blocks == 4:                    # A₁, B₁: the first quarter's events again
                add(c + shift, values, slot - first_slot < quarter)
            return (j + 1,)

        dr.while_loop(state=(dr.zeros(mi.UInt32, dr.width(local)),), cond=lambda j: j < count,
                      body=body, labels=("j",), label="pixel sums")


def _mark(words, cell, active) -> None:
    """Set the bits of ``cell`` in the bitmap ``words`` (an atomic OR: any order, same result)."""
    dr.scatter_reduce(dr.ReduceOp.Or, words, mi.UInt32(1) << (cell & 31), cell >> 5, active)


class _Ranks:
    """The rank of a cell among the occupied cells (the number of occupied cells before it: an
    occupied cell's index in the tile's sorted cells, CSR order), from the bitmap and the count
    of occupied cells in the words before its own."""

    def __init__(self, words):
        self.words = words
        counts = dr.popcnt(words)
        self.before = dr.prefix_sum(counts)        # exclusive
        dr.eval(self.before)
        self.total = int(dr.sum(counts).numpy()[0])

    def __call__(self, cell, active):
        word = cell >> 5
        below = dr.gather(mi.UInt32, self.words, word, active) & ((mi.UInt32(1) << (cell & 31)) - 1)
        return dr.gather(mi.UInt32, self.before, word, active) + dr.popcnt(below)


def _lane_cells(lane, n: int, spp: int, split: int, blocks: int):
    """Each lane's pixel row, sample block (0: A, 1: B) and whether its sample lies in the first
    half of its block (the layout of :func:`~methods.symbolic.trace.events.lane_pixel`)."""
    row = lane_pixel(lane, n, spp, split)
    if blocks == 1:
        return row, dr.zeros(mi.UInt32, dr.width(lane)), mi.Bool(False)
    first = dr.opaque(mi.UInt32, n * split)
    in_b = lane >= first
    block = dr.select(in_b, mi.UInt32(1), mi.UInt32(0))
    if blocks == 2:
        return row, block, mi.Bool(False)
    sample = dr.select(in_b, (lane - dr.select(in_b, first, 0)) % dr.opaque(mi.UInt32, spp - split),
                       lane % dr.opaque(mi.UInt32, split))
    return row, block, sample < dr.opaque(mi.UInt32, spp // 4)


def _matrices(summed, n: int, n_cols: int, spp: int, split: int, blocks: int) -> tuple:
    """The blocks' canonical CSR matrices, reweighted to full estimates (:func:`_summed`'s rows)."""
    indptr, cols, values = summed

    def csr(k: int, weight: float) -> list:
        lo, hi = indptr[k * n], indptr[(k + 1) * n]
        rows = indptr[k * n:(k + 1) * n + 1] - lo
        mats = []
        for v in values:
            data = v[lo:hi]
            if weight != 1.0:
                data *= weight                      # in place: the sums are this tile's own
            mat = sp.csr_matrix((data, cols[lo:hi], rows), shape=(n, n_cols))
            mat.has_canonical_format = True
            mats.append(mat)
        return mats

    if blocks == 1:
        return (csr(0, 1.0),)
    halves = csr(0, spp / split), csr(1, spp / (spp - split))
    if blocks == 2:
        return halves
    return halves + (csr(2, spp / (spp // 4)), csr(3, spp / (spp // 4)))
