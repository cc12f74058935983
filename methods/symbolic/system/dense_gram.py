"""A Gram system's matrices held dense: the steps of a fit on full symmetric arrays.

The field path sums a lens's views into dense matrices when they are small
(:func:`~methods.symbolic.system.view_systems.dense_sum`); its systems are then far from sparse
(the bundled ``urban_canyon_survey``: 2,508 monomials, half the pairs non-zero, every pair once
projected). A
:class:`~methods.symbolic.system.gram.GramSystem` made from them keeps them (its ``dense``) and
the fit's steps take them as they are: the known weights mapped out (``Mᵀ G M``), the
restriction to the observable parameters, the projection onto the positive semi-definite
matrices and the solver's cost. Cut to a sparse triangle after each step and made dense again
by the next, that scene's six fits spent 10.4 s in the conversions (summed over their calls, some
on threads; 2026-12-06), and its solve took 72.6 and 69.7 s against 70.8 and 67.1 s held dense
(passes from the cache, the two alternated). The triangles are cut only where a step has no dense
form (:class:`Triangles`).

Here the steps that differ from their sparse forms: :class:`Triangles`, :func:`psd` (with
:func:`psd_projection`, which the sparse form uses as well) and :func:`sandwich`.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from methods.symbolic.system.upper_triangle import dense_triangle, mirror_upper


class Triangles(Sequence):
    """The upper triangles (CSR, exact zeros left out) of dense symmetric matrices, each cut at
    its first use and kept: a :class:`~methods.symbolic.system.gram.GramSystem`'s ``G`` when it
    holds ``dense``. Read-only: a system that changes its matrices cuts them all first."""

    def __init__(self, dense: Sequence):
        self._dense = dense
        self._cut: list = [None] * len(dense)

    def __len__(self) -> int:
        return len(self._dense)

    def __getitem__(self, c):
        if isinstance(c, slice):
            return [self[k] for k in range(len(self))[c]]
        if self._cut[c] is None:
            self._cut[c] = dense_triangle(self._dense[c])
        return self._cut[c]

    def cut(self) -> list:
        """Whichever triangles exist already (None for the others), for their bytes."""
        return list(self._cut)


def triangle_nnz(d: np.ndarray) -> int:
    """Non-zeros of the upper triangle (diagonal included) of the symmetric ``d``: what its
    CSR triangle would store."""
    return (np.count_nonzero(d) + np.count_nonzero(d.diagonal())) // 2


def psd_projection(m: np.ndarray) -> np.ndarray:
    """The symmetric ``m`` with its negative eigenvalues set to 0: ``m + W Wᵀ`` with ``W`` the
    eigenvectors of the negative ones scaled by ``√-λ``, or ``U Uᵀ`` with the positive ones, whichever
    has fewer columns (one symmetric rank-k product, half a general one: bundled urban_canyon_survey's
    2,568 monomials have 973 negative eigenvalues). A new array; ``m`` is left as it was."""
    w, V = np.linalg.eigh(m)
    negative = w < 0.0
    if 2 * np.count_nonzero(negative) < len(w):
        W = V[:, negative] * np.sqrt(-w[negative])
        out = W @ W.T
        out += m                 # in place: one N² temporary fewer (the same sum as m + W Wᵀ)
        return out
    U = V[:, ~negative] * np.sqrt(w[~negative])
    return U @ U.T


def psd(dense: Sequence, limit: int) -> tuple[list, list[int]]:
    """Each ``(N, N)`` symmetric matrix of ``dense`` projected onto the positive semi-definite
    matrices, one connected component at a time, and the sizes of the components of more than
    ``limit`` monomials, left unprojected, listed for each matrix (:meth:`GramSystem.psd
    <methods.symbolic.system.gram.GramSystem.psd>` gives the why).

    The components are those of the channels' summed pattern: a block-diagonal matrix projects
    block by block, so a component that joins two of one channel's projects them exactly too.
    One component over every monomial (the bundled survey's) is projected without a copy in or
    out. New arrays; ``dense`` is left as it was.
    """
    labels = components(np.logical_or.reduce([d != 0 for d in dense]))
    n_comp = int(labels.max()) + 1 if len(labels) else 0
    sizes = np.bincount(labels, minlength=n_comp)
    if n_comp == 1 and sizes[0] <= limit:
        return [psd_projection(d) for d in dense], []
    order = np.argsort(labels, kind="stable")          # each component: a contiguous, increasing run
    bounds = np.concatenate([[0], np.cumsum(sizes)])
    parts = [order[bounds[k]:bounds[k + 1]] for k in range(n_comp)]
    skipped = [len(idx) for idx in parts if len(idx) > limit] * len(dense)     # listed per matrix
    out = []
    for d in dense:
        p = np.zeros_like(d)
        for idx in parts:
            block = np.ix_(idx, idx)
            if len(idx) == 1:
                p[block] = np.maximum(d[block], 0.0)
            else:
                p[block] = d[block] if len(idx) > limit else psd_projection(d[block])
        out.append(p)
    return out, skipped


def components(pattern: np.ndarray) -> np.ndarray:
    """``(N,)`` component label of each row of the symmetric boolean ``(N, N)`` ``pattern`` (an
    edge where True), labelled in the order of their first rows: a search that takes whole rows
    of the dense pattern at a time, ``O(N²)``, where scipy's ``connected_components`` needs the
    pattern as CSR first (0.22 s for a half-full 2,508 x 2,508 pattern, 2026-12-06)."""
    N = len(pattern)
    labels = np.full(N, -1, dtype=np.int64)
    k = 0
    for first in range(N):
        if labels[first] >= 0:
            continue
        labels[first], frontier = k, np.array([first])
        while len(frontier):
            frontier = np.flatnonzero(pattern[frontier].any(axis=0) & (labels < 0))
            labels[frontier] = k
        k += 1
    return labels


def sandwich(dense: Sequence, M: list) -> list:
    """``M_cᵀ G_c M_c`` of each channel's dense ``G_c`` and sparse ``M_c`` (``(N, N')``), dense
    and exactly symmetric (its upper triangle mirrored: the two products' sums run in different
    orders): two sparse-by-dense products, ``O(nnz(M) N)`` each."""
    return [mirror_upper(np.ascontiguousarray(m.T @ np.ascontiguousarray((m.T @ d).T))) for d, m in zip(dense, M)]
