"""The feasible set of the weights: bounds and, per group of indices, Σ x <= 1 (a segment's kernel
weights in one channel); the exact Euclidean projection onto it."""
from __future__ import annotations

from typing import Sequence

import numpy as np


def group_matrix(groups: list[np.ndarray], n: int) -> np.ndarray:
    """``(len(groups), n)`` 0/1 matrix ``M`` with ``(M x)_i = Σ x[groups[i]]``."""
    M = np.zeros((len(groups), n))
    for i, g in enumerate(groups):
        M[i, g] = 1.0
    return M


def feasible(x, lo, hi, M: np.ndarray, tol: float) -> bool:
    x = np.asarray(x)
    return bool(np.all(x >= lo - tol) and np.all(x <= hi + tol) and np.all(M @ x <= 1.0 + tol))


def project_feasible(x: np.ndarray, groups: Sequence[Sequence[int]]) -> np.ndarray:
    """Projection of ``x`` ((n,) or (n, C), one column per channel) onto [0, 1] ∩ {Σ x[g] <= 1}.

    Where the clipped values of a group sum to more than 1, they are projected onto the face
    Σ x = 1 of the probability simplex (sort-based algorithm of Held et al. / Duchi et al. 2008),
    which is the exact Euclidean projection onto the feasible set in that case.
    """
    x = np.clip(np.asarray(x, dtype=float), 0.0, 1.0)
    columns = x.reshape(x.shape[0], -1)          # a view: writes land in x
    for g in groups:
        for c in range(columns.shape[1]):
            if columns[g, c].sum() > 1.0:
                columns[g, c] = _project_simplex(columns[g, c])
    return x


def _project_simplex(v: np.ndarray) -> np.ndarray:
    u = np.sort(v)[::-1]
    css = np.cumsum(u) - 1.0
    k = np.nonzero(u - css / np.arange(1, v.size + 1) > 0)[0][-1]
    return np.maximum(v - css[k] / (k + 1), 0.0)
