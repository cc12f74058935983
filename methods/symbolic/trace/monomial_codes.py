"""The multiset codes that name monomials, and the integrator's path keys mapped to them.

Every light path ``C`` of at most ``N_max`` reflections carries the radiance
``L(ρ, C) = α ∏_j ρ_j^{e_j}`` (paper eq. 7): a monomial of total degree at most ``N_max`` in
``D = dim(ρ)`` variables. It is named by its *multiset code*: the sorted parameter indices
``p_0 <= ... <= p_{d-1}`` as base-``(D + 1)`` digits ``p_i + 1`` (0: no parameter),
``Σ_i (p_i + 1)(D + 1)^i``. The constant monomial has code 0; sorted codes are ordered by degree,
then by the largest parameter. The integrator writes each contribution under the *ordered* key
of its path's parameters in the same encoding (the order the path met them), below
``(D + 1)^N_max`` (times the emitter groups: :func:`emitter_columns`), checked to fit its 32-bit
event column (:func:`check_key_range`); a tile's distinct keys are mapped to the sorted codes of
the monomials that occur (:func:`monomial_columns`), the columns of its coefficient matrices.
Every stage above the trace names monomials by these codes
(:class:`~methods.symbolic.system.basis.MonomialBasis`).
"""
from __future__ import annotations

from itertools import combinations_with_replacement

import numpy as np

from framework.errors import ConfigError


def multiset_codes(keys: np.ndarray, n_params: int, max_degree: int) -> np.ndarray:
    """Multiset codes of ordered keys ``Σ_i (p_i + 1)(D + 1)^i`` (the integrator's path keys): the
    digits decoded, sorted (non-empty ones first) and re-encoded, as int64."""
    digits = code_digits(np.asarray(keys, dtype=np.int64), n_params, max_degree)
    empty = n_params + 1                          # sorts the empty digits (0) after the others
    digits = np.sort(np.where(digits == 0, empty, digits), axis=1)
    return encode_digits(np.where(digits == empty, 0, digits), n_params)


# Largest key range canonicalised through a dense lookup table (one int32 per possible key:
# 16 MiB); beyond it the distinct keys are found by sorting.
TABLE_KEYS = 1 << 22


def monomial_columns(keys: np.ndarray, n_params: int, max_degree: int) -> tuple[np.ndarray, np.ndarray]:
    """``(codes, cols)``: the sorted multiset codes occurring among the ordered path ``keys`` and
    the column of each key among them (``codes[cols] == multiset_codes(keys)``).

    Only the distinct keys are decoded: a tile has millions of events but at most a few thousand
    distinct keys, and sorting every event (``np.unique``) would cost a third of the pass's time.
    """
    keys = np.asarray(keys, dtype=np.int64)
    span = (int(n_params) + 1) ** int(max_degree)
    if span <= TABLE_KEYS:
        seen = np.zeros(span, dtype=bool)
        seen[keys] = True
        distinct = np.flatnonzero(seen)
        position = np.zeros(span, dtype=np.int32)
        position[distinct] = np.arange(len(distinct), dtype=np.int32)
        inverse = position[keys]
    else:
        distinct, inverse = np.unique(keys, return_inverse=True)
    codes, merged = np.unique(multiset_codes(distinct, n_params, max_degree), return_inverse=True)
    return codes, merged.astype(np.int32)[inverse]


def emitter_columns(keys: np.ndarray, n_params: int, max_degree: int, n_scales: int
                    ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`monomial_columns` of path keys that carry the group of the emitter a contribution
    came from above the ``N_max`` digits (``key = κ + g (D + 1)^N_max``, ``g`` in ``[0, G]``).

    Group 0 is light of known intensity: its monomial is ``κ``'s. Group ``g >= 1`` is the
    ``g``-th unknown emitter scale, the parameter ``D + g - 1`` of a basis over ``D + G``
    parameters of degree ``N_max + 1``: its digit is appended to ``κ``'s monomial (it exceeds
    every ρ index, so the multiset stays sorted). Returns ``(codes, cols)`` in that basis.
    """
    D, N, G = int(n_params), int(max_degree), int(n_scales)
    keys = np.asarray(keys, dtype=np.int64)
    top = (D + 1) ** N
    group = keys // top
    codes_rho, cols_rho = monomial_columns(keys % top, D, N)
    pair = cols_rho.astype(np.int64) * (G + 1) + group          # few distinct: a dense table
    seen = np.zeros(len(codes_rho) * (G + 1), dtype=bool)
    seen[pair] = True
    distinct = np.flatnonzero(seen)
    digits = code_digits(codes_rho[distinct // (G + 1)], D, N)
    g = distinct % (G + 1)
    wide = np.zeros((len(distinct), N + 1), dtype=np.int64)
    wide[:, :N] = digits
    wide[np.arange(len(wide)), (digits > 0).sum(axis=1)] = np.where(g > 0, D + g, 0)
    codes, merged = np.unique(encode_digits(wide, D + G), return_inverse=True)
    position = np.zeros(len(seen), dtype=np.int32)
    position[distinct] = merged
    return codes, position[pair]


def check_key_range(n_params: int, max_degree: int, n_scales: int = 0) -> None:
    """Raise :class:`ConfigError` when the ordered path keys (``< (D + 1)^N_max``, times ``G + 1``
    with ``G`` unknown emitter scales: :func:`emitter_columns`) do not fit in the integrator's
    uint32 event column (one value is reserved for an empty slot)."""
    if (int(n_params) + 1) ** int(max_degree) * (int(n_scales) + 1) >= 2 ** 32 - 1:
        times = f" x ({n_scales} unknown emitter scales + 1)" if n_scales else ""
        raise ConfigError(f"(number of parameters + 1)^render.max_bounces{times} = ({n_params} + 1)^{max_degree}"
                          f"{times} exceeds the 32-bit path keys: lower render.max_bounces or estimate fewer "
                          "parameters (method.kernels)")


def merge_codes(*codes: np.ndarray) -> np.ndarray:
    """Sorted union of code lists (the basis of several views together)."""
    return np.unique(np.concatenate([np.asarray(c, dtype=np.int64) for c in codes]))


def code_digits(codes: np.ndarray, D: int, N: int) -> np.ndarray:
    """``(K, N)`` base-``(D + 1)`` digits of ``codes`` (digit 0: no parameter)."""
    return (codes[:, None] // (D + 1) ** np.arange(N, dtype=np.int64)) % (D + 1)


def encode_digits(digits: np.ndarray, D: int) -> np.ndarray:
    """Codes of ``(K, N)`` digit rows."""
    return (np.asarray(digits, dtype=np.int64) * (D + 1) ** np.arange(digits.shape[1], dtype=np.int64)).sum(axis=1)


def appended_codes(codes: np.ndarray, index: int | None, n_params: int, max_degree: int) -> np.ndarray:
    """The codes of the monomials ``codes`` (``max_degree`` digits of base ``n_params + 1``) each
    times parameter ``index`` (its digit appended after the used ones: ``index`` must exceed every
    parameter of the codes for the digits to stay sorted); ``codes`` for ``index`` None."""
    codes = np.asarray(codes, np.int64)
    if index is None:
        return codes
    digits = code_digits(codes, n_params, max_degree)
    if len(digits) and index + 1 <= digits.max():
        raise ValueError(f"parameter {index} would not be the last digit of every monomial")
    wide = np.zeros((len(digits), max_degree + 1), dtype=np.int64)
    wide[:, :max_degree] = digits
    wide[np.arange(len(wide)), (digits > 0).sum(axis=1)] = index + 1
    return encode_digits(wide, n_params)


def all_codes(n_params: int, max_degree: int) -> np.ndarray:
    """Sorted codes of all ``C(D + N_max, N_max)`` monomials of degree ``<= N_max``."""
    D, N = int(n_params), int(max_degree)
    rows = [np.zeros(1, np.int64)]
    for d in range(1, N + 1):
        combos = np.array(list(combinations_with_replacement(range(D), d)), dtype=np.int64).reshape(-1, d)
        rows.append(encode_digits(combos + 1, D))
    return np.sort(np.concatenate(rows))
