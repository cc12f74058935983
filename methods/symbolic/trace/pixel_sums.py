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

Memory on the device is that of the events, the bitmap (three bits per (row, monomial) cell with
its words' counts and ranks) and the summed cells (a column and ``C`` float64 sums each). At low
spp nearly every event is its own cell, and a tile summed whole held more than its events (4 spp:
1.6 times ``method.memory_mb``). So a tile is summed in chunks of pixels whose bitmap takes at
most an eighth of a full tile's event buffers (:data:`SUMS_SHARE`), each chunk marking only its
own pixels' events (two contiguous ranges of the compacted slots), and a chunk's cells, counted
from its ranks, in parts of pixels whose cells take at most as much (at the default budget a
tile is mostly one chunk and one part).

Key ranges above :data:`~methods.symbolic.trace.monomial_codes.TABLE_KEYS` (hundreds of parameters)
have no key table: :func:`pixel_sums` returns None and the caller sums on the host
(:func:`~methods.symbolic.trace.events.tile_matrices`). Both sum the float32 values in float64, in
another order: they agree to float32 rounding (``tests/methods/test_polynomial_integrator.py``).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import scipy.sparse as sp

from framework.render.arrays import device_array
from methods.symbolic.trace.events import lane_pixel
from methods.symbolic.trace.monomial_codes import TABLE_KEYS


def pixel_sums(events, *, n: int, spp: int, split: int, quarters: bool, span: int, columns,
               tile_bytes: int | None = None) -> tuple | None:
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
    tile_bytes : int, optional
        Bytes of a full tile's event buffers (``method.memory_mb``'s share; default those of
        ``events``): a chunk's bitmap, and apart a part of its summed cells, take at most
        ``tile_bytes /`` :data:`SUMS_SHARE` each.

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
    chunks = [_matrices(summed, m, len(codes), spp, split, blocks)
              for m, summed in tile.sums((tile_bytes or events.nbytes()) // SUMS_SHARE)]
    return codes, chunks[0] if len(chunks) == 1 else _stacked(chunks)


#: a chunk's bitmap, counts and ranks, and apart a part's summed cells, take at most a full tile's
#: event buffers' bytes over this. Measured (Dr.Jit's allocation watermark, urban_canyon street_002,
#: 2026-12-06): at 4 instead of 8 the 8-spp and 16-spp passes at memory_mb 16 peaked at 16.5 and
#: 17.1 MiB (Dr.Jit rounds each buffer up to a power of two); at 8 the 1920x1080 / 64-spp pass's
#: 48 tiles were summed in 53 parts (48 at 4), no slower (36.7 against 37.0 s)
SUMS_SHARE = 8
#: and a chunk's bitmap at most this many (row, monomial) cells (32-bit cell numbers)
CHUNK_CELLS = 2 ** 28


def _chunk_bounds(costs: list[np.ndarray], budgets: list[float]) -> list[tuple[int, int]]:
    """``(first pixel, pixels)`` of consecutive chunks whose summed per-pixel ``costs`` each stay
    within their ``budgets``, every chunk of at least one pixel."""
    totals, bounds, p0 = [np.cumsum(c) for c in costs], [], 0
    while p0 < len(costs[0]):
        stop = min(int(np.searchsorted(t, (t[p0 - 1] if p0 else 0) + b, side="right")) for t, b in zip(totals, budgets))
        bounds.append((p0, max(1, stop - p0)))
        p0 += bounds[-1][1]
    return bounds


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
    dr.scatter(table, device_array(mi.UInt32, cols), distinct)
    return np.asarray(codes, np.int64), table


def _no_sums(rows: int, n_channels: int) -> tuple:
    """The CSR arrays of ``rows`` rows without events (:meth:`_Tile.sums`)."""
    return np.zeros(rows + 1, np.int32), np.zeros(0, np.int32), [np.zeros(0) for _ in range(n_channels)]


class _Tile:
    """A tile's events (``at``: the slots that hold one) and each summing row's first event and
    count (step 2), summed a chunk of pixels at a time (:meth:`sums`).

    The summing rows are those of the blocks A (and B), tile-wide ``b · n + pixel``; their events
    are contiguous in slot order, so a chunk's are two ranges of ``at``, and a chunk's work and
    memory are those of its own events. A chunk of ``m`` pixels from ``p0`` has rows
    ``b · m + (pixel - p0)``, block-major; with quarters, rows ``(b + 2) · m + ...`` hold again
    the events of the first half of block ``b``'s samples (``A₁``, ``B₁``).
    """

    def __init__(self, events, at, table, *, n: int, spp: int, split: int, n_cols: int, blocks: int):
        self.events, self.at, self.table, self.n, self.n_cols, self.blocks = events, at, table, n, n_cols, blocks
        self.slots, self.spp, self.split = events.slots, spp, split
        pixel, block, _ = _lane_cells(at // dr.opaque(mi.UInt32, events.slots), n, spp, split, blocks)
        self.events_per_row = dr.zeros(mi.UInt32, n * min(blocks, 2))
        dr.scatter_add(self.events_per_row, mi.UInt32(1), block * dr.opaque(mi.UInt32, n) + pixel)
        self.first_event = dr.prefix_sum(self.events_per_row)  # exclusive: each row's first event in ``at``
        self._start = None

    def sums(self, budget: float) -> list[tuple[int, tuple]]:
        """``(m, (indptr, cols, [values per channel]))`` of consecutive chunks of ``m`` pixels:
        the occupied (row, column) cells in CSR form over the chunk's ``blocks · m`` rows (row
        ``k``'s cells are ``indptr[k] .. indptr[k + 1] - 1``, with their columns, increasing,
        and summed values; step 3).

        Each chunk's bitmap, its words' counts and ranks (3 bits per (row, monomial)) fit in
        ``budget`` bytes; its occupied cells, counted from them, are summed in parts of pixels
        whose cells fit in ``budget`` too (a column and ``C`` float64 sums each)."""
        grid = np.full(self.n, self.blocks * self.n_cols)                  # (row, monomial) cells of a pixel
        bounds = _chunk_bounds([grid * 3 / 8, grid], [budget, CHUNK_CELLS])
        out = []
        for p0, m in bounds:
            out += self._chunk(p0, m, budget, several=len(bounds) > 1)
        return out

    def _ranges(self, p0: int, m: int) -> list[tuple[int, int]]:
        """The ranges of ``at`` that hold the events of pixels ``p0 .. p0 + m - 1``, one per block
        (the whole tile: one range)."""
        if m == self.n:
            return [(0, dr.width(self.at))]
        if self._start is None:                                  # each summing row's first event
            self._start = np.concatenate([[0], np.cumsum(self.events_per_row.numpy(), dtype=np.int64)])
        return [(int(self._start[b * self.n + p0]), int(self._start[b * self.n + p0 + m]))
                for b in range(min(self.blocks, 2))]

    def _chunk(self, p0: int, m: int, budget: float, several: bool) -> list[tuple[int, tuple]]:
        """Mark and rank the occupied cells of pixels ``p0 .. p0 + m - 1``, then sum them in parts
        (:meth:`sums`)."""
        ranges = self._ranges(p0, m)
        lanes = sum(hi - lo for lo, hi in ranges)
        if lanes == 0:
            return [(m, _no_sums(self.blocks * m, len(self.events.values)))]
        words = dr.zeros(mi.UInt32, self.blocks * m * self.n_cols // 32 + 1)     # one past the last cell
        shift = dr.opaque(mi.UInt32, 2 * m * self.n_cols)                  # to the rows of A₁, B₁
        cell, first_quarter = self._cells(ranges, lanes, p0, m)
        _mark(words, cell, True)
        if self.blocks == 4:
            _mark(words, cell + shift, first_quarter)
        rank = _Ranks(words)
        # each row's first rank, and past the last row the count of occupied cells
        starts = rank(dr.arange(mi.UInt32, self.blocks * m + 1) * dr.opaque(mi.UInt32, self.n_cols), True)
        starts = starts.numpy().astype(np.int64)
        per_pixel = np.diff(starts).reshape(self.blocks, m).sum(0)
        parts = _chunk_bounds([per_pixel * (4 + 8 * len(self.events.values))], [budget])
        copy = several or len(parts) > 1
        return [(mq, self._part(p0, m, q0, mq, starts, shift, rank, copy)) for q0, mq in parts]

    def _part(self, p0: int, m: int, q0: int, mq: int, starts: np.ndarray, shift, rank, copy: bool) -> tuple:
        """The summed cells of the chunk's pixels ``q0 .. q0 + mq - 1`` (chunk-relative), block by
        block: block ``k``'s cells are ranks ``starts[k m + q0] .. starts[k m + q0 + mq] - 1`` of
        the chunk's. ``copy``: the sums leave Dr.Jit's memory (on ``llvm_*`` ``numpy()`` shares
        it), where the next part takes their buffers again; parts are stacked anyway."""
        rows = np.arange(self.blocks) * m + q0
        lo, hi = starts[rows], starts[rows + mq]
        base = lo - np.concatenate([[0], np.cumsum(hi - lo)[:-1]])         # block k's rank -> its place
        total = int((hi - lo).sum())
        index = np.int32 if total < 2 ** 31 else np.int64          # scipy's index type for this size
        cols = dr.zeros(mi.UInt32, total)
        sums = [dr.zeros(mi.Float64, total) for _ in self.events.values]
        if total:
            self._row_sums(p0, m, q0, mq, shift, rank, base, cols, sums)
        indptr = np.concatenate([starts[r:r + mq] - b for r, b in zip(rows, base)] + [[total]]).astype(index)
        return indptr, cols.numpy().astype(index), [np.array(v.numpy()) if copy else v.numpy() for v in sums]

    def _cells(self, ranges, lanes: int, p0: int, m: int):
        """The chunk's events' cells, and whether each lies in the first half of its block's
        samples: one lane per event of the chunk's ranges of ``at`` (:meth:`_ranges`)."""
        i = dr.arange(mi.UInt32, lanes)
        (a0, a1), *rest = ranges
        e = dr.opaque(mi.UInt32, a0) + i
        if rest:
            in_b = i >= dr.opaque(mi.UInt32, a1 - a0)
            e = dr.select(in_b, dr.opaque(mi.UInt32, rest[0][0] - (a1 - a0)) + i, e)
        slot = dr.gather(mi.UInt32, self.at, e)
        pixel, block, first_quarter = _lane_cells(slot // dr.opaque(mi.UInt32, self.slots), self.n, self.spp,
                                                  self.split, self.blocks)
        row = block * dr.opaque(mi.UInt32, m) + pixel - dr.opaque(mi.UInt32, p0)
        return row * dr.opaque(mi.UInt32, self.n_cols) + self._column(slot), first_quarter

    def _column(self, slot):
        """The monomial column of the events in ``slot``s (the key table of step 1)."""
        return dr.gather(mi.UInt32, self.table, dr.gather(mi.UInt32, self.events.mono, slot))

    def _row_sums(self, p0: int, m: int, q0: int, mq: int, shift, rank, base, cols, sums) -> None:
        """Each occupied cell's column and sum, written at its rank less its block's ``base``: one
        lane per summing row of the chunk's pixels ``q0 .. q0 + mq - 1`` walks that row's events
        in slot order, so each cell is summed by one lane in one order: the same seed gives the
        same bits on any backend and thread count (atomic adds from many lanes sum in a
        scheduling-dependent order)."""
        n, slots, size = self.n, dr.opaque(mi.UInt32, self.slots), dr.opaque(mi.UInt32, mq)
        local = dr.arange(mi.UInt32, mq * min(self.blocks, 2))            # the part's summing row, block-major
        in_b = local >= size
        offset = local - dr.select(in_b, size, 0)
        pixel = dr.opaque(mi.UInt32, p0 + q0) + offset
        r = dr.select(in_b, dr.opaque(mi.UInt32, n), 0) + pixel             # the tile-wide summing row
        count = dr.gather(mi.UInt32, self.events_per_row, r)
        first_event = dr.gather(mi.UInt32, self.first_event, r)
        per_pixel = dr.select(in_b, dr.opaque(mi.UInt32, self.spp - self.split), dr.opaque(mi.UInt32, self.split))
        # block B's pixel p starts at lane n·split + p·(spp - split)
        first_slot = (dr.select(in_b, dr.opaque(mi.UInt32, n * self.split), 0) + pixel * per_pixel) * slots
        quarter = dr.opaque(mi.UInt32, (self.spp // 4) * self.slots)
        n_cols = dr.opaque(mi.UInt32, self.n_cols)
        row_cell = (dr.select(in_b, dr.opaque(mi.UInt32, m), 0) + dr.opaque(mi.UInt32, q0) + offset) * n_cols
        bases = [dr.opaque(mi.UInt32, int(b)) for b in base]
        own = dr.select(in_b, bases[1], bases[0]) if len(bases) > 1 else bases[0]
        again = dr.select(in_b, bases[3], bases[2]) if len(bases) == 4 else None

        def add(c, k, values, active):
            # a lane's cells are its row's alone: no two lanes of a packet reach the same one
            where = rank(c, active) - k
            dr.scatter(cols, c % n_cols, where, active)
            for total, v in zip(sums, values):
                dr.scatter_add(total, mi.Float64(v), where, active, mode=dr.ReduceMode.NoConflicts)

        def body(j):
            slot = dr.gather(mi.UInt32, self.at, first_event + j)
            c = row_cell + self._column(slot)
            values = [dr.gather(mi.Float, v, slot) for v in self.events.values]
            add(c, own, values, True)
            if self.blocks == 4:                    # A₁, B₁: the first quarter's events again
                add(c + shift, again, values, slot - first_slot < quarter)
            return (j + 1,)

        dr.while_loop(state=(dr.zeros(mi.UInt32, dr.width(local)),), cond=lambda j: j < count,
                      body=body, labels=("j",), label="pixel sums")


def _mark(words, cell, active) -> None:
    """Set the bits of ``cell`` in the bitmap ``words`` (an atomic OR: any order, same result).
    Direct atomics: on ``llvm_*`` Dr.Jit's default expands a target below a million words into a
    copy per thread, outside the chunk's budget (no slower measured on the 1920x1080 pass)."""
    dr.scatter_reduce(dr.ReduceOp.Or, words, mi.UInt32(1) << (cell & 31), cell >> 5, active, mode=dr.ReduceMode.Direct)


class _Ranks:
    """The rank of a cell among the occupied cells (the number of occupied cells before it: an
    occupied cell's index in the tile's sorted cells, CSR order), from the bitmap and the count
    of occupied cells in the words before its own."""

    def __init__(self, words):
        self.words = words
        self.before = dr.prefix_sum(dr.popcnt(words))        # exclusive
        dr.eval(self.before)

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
