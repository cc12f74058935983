"""The Gram systems of a view's coefficients: pixel-weighted, per owner, one row block at a time.

A view's coefficients (:class:`~methods.symbolic.system.coefficients.ViewCoefficients`, or
:class:`~methods.symbolic.system.coefficients.TiledCoefficients` loaded one tile at a time) give
the Gram system of its pixels, pixel ``p`` weighted by ``w_p`` (:func:`weighted_system`): the
cost ``Σ_p w_p (γ_p·μ - y_p)²``, with the cross Gram of the two half-sample estimates when the
pass kept them. The pass builds each view's own system so (weights None), the field path
rebuilds them with its pixel weights every robust round, the per-segment fit one per parameter
block from the pixels the block owns (:func:`owned_systems`).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from methods.symbolic.system.gram import GramSystem
from methods.symbolic.system.pixel_matrices import scale_rows


def weighted_system(coeffs, y: np.ndarray, weights: np.ndarray | None, *, threads: bool = False) -> GramSystem:
    """The Gram system of one view from its coefficients, pixel ``p`` weighted by ``w_p``.

    With the two half-sample estimates ``a`` and ``b``, the cross Gram ½(AᵀWB + BᵀWA)
    (:meth:`GramSystem.accumulate_sparse`, rows scaled by √w); without ``b``, ΓᵀWΓ. With
    ``weights`` None this is the pass's own system
    (:func:`~methods.symbolic.system.polynomial_pass.polynomial_pass` builds it so). One row block of
    the coefficients at a time (:func:`row_blocks`: a tiled view's are loaded one by one).

    Parameters
    ----------
    coeffs : ViewCoefficients or TiledCoefficients
    y : numpy.ndarray
        ``(n, C)`` observed pixels.
    weights : numpy.ndarray or None
        ``(n,)`` weights >= 0 (None: all 1).
    threads : bool
        Channels side by side (:meth:`GramSystem.accumulate_sparse`): for a system formed again
        each robust round.
    """
    total = None
    for block, y_rows, w_rows in row_blocks(coeffs, y, weights):
        total = summed(total, _block_system(block, y_rows, w_rows, threads=threads))
    return total


def summed_views(views) -> GramSystem:
    """``Σ_v`` :func:`weighted_system` of the views, ``(coeffs, y, weights)`` triples, summed in
    their order, for a system formed again and again (the field path's fits).

    When every block keeps the coefficients before a lens's expansion (its ``factors``) and the
    summed matrices are small (:data:`DENSE_SYSTEM_BYTES`), they are formed from those and summed
    dense (:func:`dense_sum`); otherwise as sparse systems: the first
    view's channels side by side (``threads``), the others two views at a time, each view's
    channels in turn (three channels on two cores leave one idle a third of the time, two views
    do not; bundled urban_canyon_survey, 2026-12-05: 11.0-11.5 s a fit's systems one view at a
    time, 8.2-8.3 s two at a time), while the first view's system is small
    (:data:`~methods.symbolic.system.gram.PARALLEL_CHANNEL_BYTES` a channel). Either way the sum
    does not depend on the machine: the same views' parts, added in the same order.
    """
    from framework.threads import run_threads, two_at_a_time
    from methods.symbolic.system.gram import PARALLEL_CHANNEL_BYTES
    views = list(views)
    parts = _factored_parts(views)
    if parts is not None:
        codes = np.unique(np.concatenate([block.codes for block, _, _ in parts]))
        if dense_bytes(parts, len(codes), parts[0][1].shape[1]) <= DENSE_SYSTEM_BYTES:
            return dense_sum(parts, codes)
    total = weighted_system(*views[0], threads=True)
    rest = views[1:]
    if total.nbytes() > PARALLEL_CHANNEL_BYTES * total.n_channels:
        for view in rest:
            total += weighted_system(*view, threads=True)
        return total
    for pair in two_at_a_time(rest):
        parts = run_threads([lambda v=v: weighted_system(*v) for v in pair]) if len(pair) == 2 \
            else [weighted_system(*pair[0], threads=True)]
        for part in parts:
            total += part
    return total


#: the field path sums its views' systems from a lens's factors as dense matrices when they take
#: at most this many bytes (``8 C N²`` for ``N`` monomials, and the lenses' products ``8 C K U²``:
#: bundled urban_canyon_survey, 2,508 monomials, 218 MB), and as sparse ones above. Coefficients
#: without factors are summed sparse: scattered into a dense sum, their products took 10.8 s a fit
#: against 8.5 s (the same survey with the factors dropped, 2026-12-05)
DENSE_SYSTEM_BYTES = 256 * 2**20


def _factored_parts(views) -> list | None:
    """The row blocks ``(block, y, w)`` of the views when every block is held and has its
    ``factors``, else None (a block waiting in the cache is not read twice)."""
    if not all(getattr(coeffs, "held", True) for coeffs, _, _ in views):
        return None
    parts = [part for view in views for part in row_blocks(*view)]
    return parts if all(block.factors is not None for block, _, _ in parts) else None


def _lenses(parts) -> dict:
    """Lens key -> ``(a block's factors, the sorted union of the base codes of the blocks with
    that lens)`` (:class:`~methods.symbolic.system.row_factors.RowFactors`), every block with its
    ``factors`` (:func:`_factored_parts`)."""
    seen: dict = {}
    for block, _, _ in parts:
        f = block.factors
        first, codes = seen.get(f.lens, (f, []))
        seen[f.lens] = (first, codes + [f.codes])
    return {key: (f, np.unique(np.concatenate(codes))) for key, (f, codes) in seen.items()}


def dense_bytes(parts, n_monomials: int, n_channels: int) -> int:
    """Bytes :func:`dense_sum` holds: the ``(N, N)`` matrices and each lens's products, per channel."""
    lens = sum(f.alpha.shape[2] * len(u) ** 2 for f, u in _lenses(parts).values())
    return 8 * n_channels * (n_monomials ** 2 + lens)


def dense_sum(parts, codes: np.ndarray) -> GramSystem:
    """:func:`summed_views` as dense matrices over ``codes`` (the union of the blocks' codes) from
    the row blocks ``parts`` (``(block, y, w)``, :func:`row_blocks`), each with its ``factors``:
    a block's products ``H_k`` are added to its lens's, expanded once at the end
    (:mod:`~methods.symbolic.system.row_factors`), and the system held dense
    (:meth:`GramSystem.from_dense <methods.symbolic.system.gram.GramSystem.from_dense>`).

    The work is six tasks on threads, each channel's blocks in two halves (:data:`DENSE_SPLITS`),
    each half summed in its blocks' order and the halves added in theirs: the sum is the same
    whatever the thread count, and two cores stay busy, where three channels side by side left
    one idle a third of the time; the expansions and the triangles are a channel a task
    (bundled urban_canyon_survey, 2026-12-05: a fit's systems 4.4 s a channel a task, 3.5-3.8 s
    so, 8.3-8.6 s sparse from the expanded coefficients).
    """
    from framework.threads import run_threads
    from methods.symbolic.system.row_factors import add_factored_products, expanded_gram
    lenses = _lenses(parts)
    C, N = len(parts[0][0].a), len(codes)
    cuts = np.linspace(0, len(parts), DENSE_SPLITS + 1).round().astype(int)

    def products(c: int, lo: int, hi: int) -> tuple[dict, np.ndarray]:
        """The lenses' summed ``[H_0ᵀ | H_1ᵀ | ...]`` and ``b`` of channel ``c`` over the blocks ``lo:hi``."""
        H = {key: np.zeros((len(u), f.alpha.shape[2] * len(u))) for key, (f, u) in lenses.items()}
        b = np.zeros(N)
        for block, y, w in parts[lo:hi]:
            b[np.searchsorted(codes, block.codes)] += _block_b(block, c, y[:, c], w)
            f = block.factors
            add_factored_products(H[f.lens], f, c, w, lenses[f.lens][1])
        return H, b

    halves = run_threads([lambda c=c, lo=lo, hi=hi: products(c, lo, hi)
                          for c in range(C) for lo, hi in zip(cuts[:-1], cuts[1:])])
    G, b = np.zeros((C, N, N)), np.zeros((C, N))
    # where each copy of each lens's base monomials sits in ``codes``: the same for every channel
    positions = {key: np.searchsorted(codes, f.expanded_codes(u)) for key, (f, u) in lenses.items()}

    def expand(c: int) -> None:
        """Channel ``c``'s halves added, each lens's ``H`` expanded into ``G_c``."""
        mine = halves[c * DENSE_SPLITS:(c + 1) * DENSE_SPLITS]
        b[c] = sum(h[1] for h in mine)
        for key, (f, u) in lenses.items():
            U = len(u)          # (U, K U) -> (K, U, U): H_kᵀ, as good as H_k (symmetrised)
            H = np.ascontiguousarray(sum(h[0].pop(key) for h in mine).reshape(U, -1, U).transpose(1, 0, 2))
            pos = positions[key]
            for t, v, part in expanded_gram(H, f.alpha):
                G[c][np.ix_(pos[t], pos[v])] += part
                if v != t:
                    G[c][np.ix_(pos[v], pos[t])] += part.T
    run_threads([lambda c=c: expand(c) for c in range(C)])
    yy = sum((np.square(y) * (1.0 if w is None else w[:, None])).sum(axis=0) for _, y, w in parts)
    return GramSystem.from_dense(G, b, yy, sum(block.n_rows for block, _, _ in parts), codes)


#: :func:`dense_sum` splits each channel's blocks into this many consecutive parts, each a task
DENSE_SPLITS = 2


def _block_b(block, c: int, y: np.ndarray, weights: np.ndarray | None) -> np.ndarray:
    """``b`` of channel ``c`` of one block: ``ΓᵀWy`` with Γ the halves' mean (with halves)."""
    wy = y if weights is None else weights * y
    if block.b is None:
        return block.a[c].T @ wy
    return 0.5 * (block.a[c].T @ wy + block.b[c].T @ wy)


def summed(total: GramSystem | None, part: GramSystem) -> GramSystem:
    """``total += part`` in place (:meth:`GramSystem.__iadd__`), or ``part`` when ``total`` is None."""
    if total is None:
        return part
    total += part
    return total


def owned_systems(coeffs, y: np.ndarray, weights: np.ndarray | None, owned: np.ndarray) -> list[GramSystem]:
    """One Gram system per column of ``owned``: :func:`weighted_system` of the pixels that
    column owns, every system from the same single pass over the view's row blocks.

    Parameters
    ----------
    coeffs, y, weights
        As for :func:`weighted_system`.
    owned : numpy.ndarray
        ``(n, K)`` bool: pixel ``p`` enters system ``k`` when ``owned[p, k]``.

    Returns
    -------
    list
        ``K`` GramSystem, None where no pixel is owned.
    """
    owned = np.asarray(owned, bool).reshape(coeffs.n_rows, -1)
    systems: list = [None] * owned.shape[1]
    start = 0
    for block, y_rows, w_rows in row_blocks(coeffs, y, weights):
        rows = owned[start:start + block.n_rows]
        start += block.n_rows
        for k in np.flatnonzero(rows.any(axis=0)):
            idx = np.flatnonzero(rows[:, k])          # the owned rows only: K systems cost one
            rows_k = dataclasses.replace(block, a=[m[idx] for m in block.a], factors=None,
                                         b=None if block.b is None else [m[idx] for m in block.b])
            systems[k] = summed(systems[k], _block_system(rows_k, y_rows[idx], None if w_rows is None else w_rows[idx]))
    return systems


def row_blocks(coeffs, y: np.ndarray, weights: np.ndarray | None = None):
    """``(block, y rows, weight rows or None)`` of each row block of a view's coefficients
    (their ``blocks()``; a tiled view's blocks are loaded one at a time), with the block's rows
    of the ``(n, C)`` observed pixels ``y`` and of the ``(n,)`` pixel ``weights``."""
    y = np.asarray(y, dtype=np.float64).reshape(coeffs.n_rows, -1)
    w = None if weights is None else np.asarray(weights, dtype=np.float64).reshape(coeffs.n_rows)
    for start, block in coeffs.blocks():
        rows = slice(start, start + block.n_rows)
        yield block, y[rows], None if w is None else w[rows]


def _block_system(coeffs, y: np.ndarray, weights: np.ndarray | None, *, threads: bool = False) -> GramSystem:
    """:func:`weighted_system` of one block (a :class:`ViewCoefficients`)."""
    C = len(coeffs.a)
    root = None if weights is None else np.sqrt(weights)
    scaled = lambda m: m if root is None else scale_rows(m, root)
    y = y if weights is None else y * root[:, None]
    A = [scaled(m) for m in coeffs.a]
    B = None if coeffs.b is None else [scaled(m) for m in coeffs.b]
    return GramSystem.zeros(coeffs.codes, C).accumulate_sparse(A, y, B, threads=threads)
