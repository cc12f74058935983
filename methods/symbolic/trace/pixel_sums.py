"""A tile's events summed per pixel and monomial where they were traced (Dr.Jit, ``llvm_*`` and
``cuda_*`` alike): what reaches the host is the tile's coefficients, never its events.

A tile of ``n`` pixels x ``spp`` samples writes ``spp × slots`` event slots per pixel
(:class:`~methods.symbolic.trace.events.EventBuffer`); a pixel's coefficients over the monomials that
occur are 1-6 % as many numbers. On a GPU, copying the events out and summing them with numpy
was 95 % of the pass; here the device does it, in three steps and one small host step:

1. the ordered path keys that occur are marked in a table over the key range and compacted: the
   host receives the distinct keys (a few hundred), maps them to monomial columns
   (:func:`~methods.symbolic.trace.monomial_codes.monomial_columns`, or ``emitter_columns`` with unknown emitter
   scales) and sends back the key -> column table;
2. each non-empty event gets its cell ``(block · n + pixel) · N_e,tile + column`` (the blocks are
   the sample halves ``A``, ``B``; with ``quarters`` the first halves ``A₁``, ``B₁`` are their
   events again, two blocks on), the cells are radix-sorted (``dr.argsort``), and each run of
   equal cells is summed as the difference of a float64 prefix sum (``dr.prefix_sum``) at its two
   ends: deterministic, where atomic adds (``dr.scatter_reduce``) sum in a thread-dependent order
   and so round differently from run to run;
3. the runs' cells and sums are copied out: sorted by (block, pixel, column), each block arrives
   as a canonical CSR matrix.

Memory on the device is that of the non-empty events (a fraction of the event buffer the tile
size is chosen for, ``method.memory_mb``). Key ranges above
:data:`~methods.symbolic.trace.monomial_codes.TABLE_KEYS` (hundreds of parameters) have no key table:
:func:`pixel_sums` returns None and the caller sums on the host
(:func:`~methods.symbolic.trace.events.tile_matrices`). Sums are float64 prefix-sum differences on the
device (the host path sums the float32 values in float64): the two agree to float32 rounding
(``tests/methods/test_polynomial_integrator.py``).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import scipy.sparse as sp

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
        ``(Γ,)``, ``(A, B, Γ)`` or ``(A, B, Γ, A₁, B₁)``, each a list of ``C`` canonical float64
        ``csr_matrix`` of shape ``(n, len(codes))``.
    """
    if span > TABLE_KEYS:
        return None
    dr.eval(events.mono, events.values)
    keep = events.nonempty()
    codes, table = _key_table(events.mono, keep, span, columns)
    halves = split < spp
    blocks = (4 if quarters else 2) if halves else 1
    if blocks * n * len(codes) >= 2 ** 32:          # cells are 32-bit: a huge tile of many monomials
        return None
    sums = _summed(events, keep, table, n=n, spp=spp, split=split, n_cols=len(codes), blocks=blocks)
    return codes, _matrices(sums, n, len(codes), spp, split, blocks)


def _key_table(mono, keep, span: int, columns) -> tuple[np.ndarray, object]:
    """The codes occurring in the tile and the device table key -> column (step 1)."""
    seen = dr.zeros(mi.UInt32, span)
    dr.scatter(seen, mi.UInt32(1), mono, keep)
    distinct = dr.compress(seen != 0)              # sorted: the keys that occur
    keys = distinct.numpy().astype(np.int64)
    if len(keys) == 0:
        return np.zeros(1, np.int64), dr.zeros(mi.UInt32, span)
    codes, cols = columns(keys)
    table = dr.zeros(mi.UInt32, span)
    dr.scatter(table, mi.UInt32(cols.astype(np.uint32)), distinct)
    return np.asarray(codes, np.int64), table


def _summed(events, keep, table, *, n: int, spp: int, split: int, n_cols: int, blocks: int):
    """``(cells, [values per channel])``: the (block, pixel, column) cells the tile's events reach,
    as flat indices ``(block · n + pixel) · n_cols + column`` in increasing order, and each cell's
    summed values (steps 2 and 3). The quarters' cells (blocks 2 and 3) are their blocks' events
    again, those of the first half of each block's samples."""
    at = dr.compress(keep)                          # the events only: a fraction of the slots
    if dr.width(at) == 0:                           # no light reached the tile (and Dr.Jit cannot
        return np.zeros(0, np.int64), [np.zeros(0) for _ in events.values]   # divide an empty array)
    lane = at // dr.opaque(mi.UInt32, events.slots)
    row, block, first_quarter = _lane_cells(lane, n, spp, split, blocks)
    col = dr.gather(mi.UInt32, table, dr.gather(mi.UInt32, events.mono, at))
    values = [dr.gather(mi.Float, v, at) for v in events.values]
    cell = (block * dr.opaque(mi.UInt32, n) + row) * dr.opaque(mi.UInt32, n_cols) + col
    parts = [_cell_sums(cell, values)]
    if blocks == 4:                                 # A₁, B₁: cells two blocks on
        sub = dr.compress(first_quarter)
        shift = dr.opaque(mi.UInt32, 2 * n * n_cols)
        parts.append(_cell_sums(dr.gather(mi.UInt32, cell, sub) + shift,
                                [dr.gather(mi.Float, v, sub) for v in values]))
    return (np.concatenate([p[0] for p in parts]),
            [np.concatenate([p[1][c] for p in parts]) for c in range(len(values))])


def _cell_sums(cell, values) -> tuple[np.ndarray, list]:
    """The distinct ``cell`` indices, sorted, and the sum of each channel's ``values`` per cell: a
    radix sort, then each run of equal cells summed as the difference of a float64 prefix sum at
    its ends. Deterministic, unlike atomic adds (whose order, and so whose float rounding, changes
    from run to run): the same seed gives the same coefficients, bit for bit."""
    if dr.width(cell) == 0:
        return np.zeros(0, np.int64), [np.zeros(0, np.float32) for _ in values]
    order = dr.argsort(cell)
    cell = dr.gather(mi.UInt32, cell, order)
    n = dr.width(cell)
    i = dr.arange(mi.UInt32, n)
    previous = dr.gather(mi.UInt32, cell, dr.maximum(i, 1) - 1)
    following = dr.gather(mi.UInt32, cell, dr.minimum(i + 1, dr.opaque(mi.UInt32, n - 1)))
    starts = dr.compress((i == 0) | (cell != previous))             # first event of each run
    ends = dr.compress((i == dr.opaque(mi.UInt32, n - 1)) | (cell != following))   # and its last
    sums = []
    for v in values:
        v64 = dr.gather(mi.Float64, mi.Float64(v), order)
        before = dr.prefix_sum(v64)                                  # exclusive: the events before
        total = dr.gather(mi.Float64, before + v64, ends) - dr.gather(mi.Float64, before, starts)
        sums.append(total)
    dr.eval(sums)
    return (dr.gather(mi.UInt32, cell, starts).numpy().astype(np.int64), [s.numpy() for s in sums])


def _lane_cells(lane, n: int, spp: int, split: int, blocks: int):
    """Each lane's pixel row, sample block (0: A, 1: B) and whether its sample lies in the first
    half of its block (the layout of :func:`~methods.symbolic.trace.events.lane_pixel`)."""
    from methods.symbolic.trace.events import lane_pixel
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


def _matrices(sums, n: int, n_cols: int, spp: int, split: int, blocks: int) -> tuple:
    """The blocks' canonical CSR matrices, reweighted to full estimates, and Γ (their weighted mean)."""
    flat, values = sums
    block, rest = np.divmod(flat, n * n_cols)
    row, col = np.divmod(rest, n_cols)
    bounds = np.searchsorted(block, np.arange(blocks + 1))

    def csr(k: int, weight: float) -> list:
        s = slice(bounds[k], bounds[k + 1])
        indptr = np.searchsorted(row[s], np.arange(n + 1))
        mats = []
        for v in values:
            mat = sp.csr_matrix((v[s].astype(np.float64) * weight, col[s].astype(np.int32), indptr),
                                shape=(n, n_cols))
            mat.has_canonical_format = True
            mats.append(mat)
        return mats

    if blocks == 1:
        return (csr(0, 1.0),)
    A, B = csr(0, spp / split), csr(1, spp / (spp - split))
    wa, wb = split / spp, (spp - split) / spp
    gamma = [(a + b) * 0.5 if wa == wb else a * wa + b * wb for a, b in zip(A, B)]
    if blocks == 2:
        return A, B, gamma
    quarter = spp // 4
    return A, B, gamma, csr(2, spp / quarter), csr(3, spp / quarter)
