"""Known weights (scene.yaml ``known``: a calibration panel) in the symbolic fit.

A segment's ``known: {kernel: value}`` holds those weights at their values: they are not
parameters of the solve. The polynomial pass still keeps them as variables (the panel lights its
surroundings and is seen: nothing in the integrator changes, and their guesses are their values,
so the kernel selection of the pass is right); the solve substitutes the values.

Substitution
    The pixel polynomials are ``γ·μ(ρ)`` over the monomials ``μ`` of every parameter. Splitting ρ
    into the known weights ``k`` and the free ones, a monomial ``∏ ρ_j^{e_j}`` is the factor
    ``∏_{j known} k_j^{e_j}`` (a number per channel) times the monomial of its free digits alone
    (the constant monomial when every digit is known). So ``μ(ρ) = M_c μ'(ρ_free)`` with a sparse
    ``M_c`` (one non-zero per row, :class:`Substitution`), exactly, per channel ``c``, and

        γ' = M_cᵀ γ,   G' = M_cᵀ G M_c,   b' = M_cᵀ b,   yy' = yy

    (the cross Gram ½(AᵀB + BᵀA) maps to the cross Gram of the mapped halves, so the unbiased Gram
    stays unbiased). The fit then runs on the free parameters only, with the per-pixel coefficients
    of the sandwich std mapped the same way (:meth:`Substitution.view`). The joint fit, the
    per-segment fit and the field path (which rebuilds its systems from the coefficients, gains
    included) all reach the solve through
    :func:`~methods.symbolic.fit.with_known.fit_with_known`.

Energy conservation
    A free kernel of a segment that also has known ones may use only what the known ones leave,
    ``Σ_free ρ <= 1 - Σ_known ρ =: s_c`` per channel. The free weight is solved as ``z = ρ / s_c``
    in the solver's ``[0, 1]`` box and ``Σ z <= 1`` (the factor ``s_c`` per free digit enters
    ``M_c``): the constraint is exact, and estimate, std and iterates are scaled back by ``s_c``
    (correlations do not change). A segment whose known weights sum to 1 leaves its free kernels
    no light to carry: they are reported unobservable.

Why not bounds ``lo = hi`` in the solver
    Holding a parameter by equal bounds would keep it in every part of the fit: the solver's box
    is one ``[0, 1]`` for all parameters (per-parameter bounds would be new in SQP, nlopt and the
    per-segment sweeps), the exact Hessian and the sandwich would carry a row and column for a
    weight that has no uncertainty (its std would come out of a pseudo-inverse of the constrained
    problem, not 0), and the ``Σρ <= 1`` of a mixed segment would need a per-segment right-hand
    side. The substitution leaves the solver, the Hessian and the sandwich as they are and gives a
    smaller, exactly equivalent problem.

Reported
    A known weight: estimate = its value, std 0, observable, never ill-determined;
    results.json marks it ``"known": true`` (:func:`framework.results.parameter_rows`).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from methods.symbolic.system import dense_gram
from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.coefficients import ViewCoefficients
from methods.symbolic.system.gram import GramSystem
from methods.symbolic.system.upper_triangle import sandwich
from methods.symbolic.trace.monomial_codes import code_digits, encode_digits, merge_codes

log = logging.getLogger(__name__)


def known_values(scene, params) -> np.ndarray | None:
    """``(P, C)`` the known value of each parameter of ``params`` (scene.yaml ``known``), NaN
    where the weight is free (gains of the field path included); None when none is known."""
    C = len(scene.channels)
    values = np.full((len(params), C), np.nan)
    for i, p in enumerate(params):
        if p.segment < 0:
            continue
        known = scene.segments[p.segment].known
        if known and p.kernel in known:
            values[i] = known[p.kernel]
    return values if np.isfinite(values).any() else None


def room(scene, params, values: np.ndarray) -> np.ndarray:
    """``(P, C)`` per parameter what its segment's known weights leave, ``max(1 - Σ_known, 0)``
    (1 where the segment has none, and for the known weights themselves)."""
    out = np.ones(values.shape)
    for i, p in enumerate(params):
        if p.segment < 0 or np.isfinite(values[i, 0]):
            continue
        known = scene.segments[p.segment].known
        if known:
            out[i] = np.maximum(1.0 - sum(known.values(), np.zeros(values.shape[1])), 0.0)
    return out


def known_guess(x0: np.ndarray, params, scene) -> np.ndarray:
    """The start ``x0`` (``(P, C)``) with each known weight at its value and the free kernels of
    a segment with known ones within what those leave (scaled down where their sum exceeds it)."""
    values = known_values(scene, params)
    if values is None:
        return x0
    x = np.array(x0, dtype=float)
    known = np.isfinite(values[:, 0])
    x[known] = values[known]
    left = room(scene, params, values)
    for s in {p.segment for p, k in zip(params, known) if not k and p.segment >= 0}:
        rows = [i for i, p in enumerate(params) if p.segment == s and not known[i]]
        total = x[rows].sum(axis=0)
        over = total > left[rows[0]]
        if over.any():
            factor = np.where(over, left[rows[0]] / np.where(total > 0, total, 1.0), 1.0)
            x[rows] *= factor
    return x


def warn_unseen(problem, params) -> list[str]:
    """Log one warning line per segment with known weights that no selected view sees through
    the centre of a usable pixel (:func:`~framework.render.mitsuba_scene.segment_maps`), and return their names: such
    a panel only lights the others (it still fixes nothing it is not seen with)."""
    values = known_values(problem.scene, params)
    if values is None:
        return []
    segments = sorted({p.segment for p, v in zip(params, values) if np.isfinite(v[0])})
    from framework.render.mitsuba_scene import segment_maps
    maps = segment_maps(problem.scene, problem.cameras)
    seen = set()
    for cam in problem.cameras:
        seg = maps[cam.name]
        w = (problem.weights or {}).get(cam.name)
        if w is not None:
            seg = np.where(np.asarray(w) > 0, seg, -1)
        seen |= set(np.unique(seg).tolist())
    unseen = [problem.scene.segments[s].name for s in segments if s not in seen]
    for name in unseen:
        log.warning("segment '%s' has known weights but no selected view sees it: it does not calibrate "
                    "this run (only its light on the others enters the fit); add a view of it", name)
    return unseen


@dataclass(frozen=True)
class Substitution:
    """The map of the monomials over every parameter onto those over the free ones (module
    docstring): ``μ(ρ) = M_c μ'(z)`` with ``ρ_free = scale · z``.

    Attributes
    ----------
    values : numpy.ndarray
        ``(P, C)`` known values, NaN for the free parameters.
    free : numpy.ndarray
        ``(F,)`` indices of the free parameters, in order.
    scale : numpy.ndarray
        ``(F, C)`` what each free weight's segment leaves (1 without known kernels): ``ρ = scale · z``.
    codes : numpy.ndarray
        ``(N',)`` sorted codes of the free monomials (base ``F + 1``), the constant included.
    old_codes : numpy.ndarray
        ``(N,)`` the codes over every parameter the map is defined on.
    column : numpy.ndarray
        ``(N,)`` the free monomial each old one maps to (index into ``codes``).
    factor : numpy.ndarray
        ``(N, C)`` its factor per channel.
    max_degree : int
    """

    values: np.ndarray
    free: np.ndarray
    scale: np.ndarray
    codes: np.ndarray
    old_codes: np.ndarray
    column: np.ndarray
    factor: np.ndarray
    max_degree: int

    @classmethod
    def build(cls, codes: np.ndarray, n_params: int, max_degree: int, values: np.ndarray,
              scale: np.ndarray | None = None) -> "Substitution":
        """The substitution of ``values`` (``(P, C)``, NaN where free) into the monomials ``codes``
        over ``n_params`` parameters of degree at most ``max_degree``; ``scale``: ``(P, C)`` factor
        of each free weight (default 1)."""
        values = np.asarray(values, dtype=float)
        P, C = values.shape
        if P != n_params:
            raise ValueError(f"values has {P} rows, the monomials {n_params} parameters")
        known = np.isfinite(values[:, 0])
        free = np.flatnonzero(~known)
        scale = np.ones((P, C)) if scale is None else np.asarray(scale, dtype=float)
        per_digit = np.ones((P + 1, C))                      # digit d = p + 1; digit 0: empty
        per_digit[1:][known] = values[known]
        per_digit[1:][~known] = scale[~known]
        renumber = np.zeros(P + 1, dtype=np.int64)            # known digits become empty
        renumber[free + 1] = np.arange(1, len(free) + 1)
        old_codes = np.asarray(codes, dtype=np.int64)
        digits = code_digits(old_codes, n_params, max_degree)
        factor = per_digit[digits].prod(axis=1)               # (N, C)
        new = renumber[digits]
        empty = len(free) + 1                                 # sorts the empty digits last
        new = np.sort(np.where(new == 0, empty, new), axis=1)
        new = np.where(new == empty, 0, new)
        mapped = encode_digits(new, max(len(free), 1))
        out = merge_codes([0], mapped)
        return cls(values, free, scale[free], out, old_codes, np.searchsorted(out, mapped), factor,
                   int(max_degree))

    @property
    def n_free(self) -> int:
        return len(self.free)

    def matrix(self, c: int, rows: np.ndarray | None = None) -> sp.csr_matrix:
        """``M_c`` (``(N, N')``), or its ``rows`` (positions in ``old_codes``)."""
        rows = np.arange(len(self.old_codes)) if rows is None else np.asarray(rows)
        return sp.csr_matrix((self.factor[rows, c], (np.arange(len(rows)), self.column[rows])),
                             shape=(len(rows), len(self.codes)))

    def basis(self) -> MonomialBasis:
        """The basis of the free monomials."""
        return MonomialBasis(self.n_free, self.max_degree, self.codes)

    def system(self, system: GramSystem) -> GramSystem:
        """``(Mᵀ G M, Mᵀ b, yy)`` per channel of a system over (a subset of) ``old_codes``."""
        rows = self._rows(system.codes)
        M = [self.matrix(c, rows) for c in range(system.n_channels)]
        b = np.stack([m.T @ bc for m, bc in zip(M, system.b)])
        if system.dense is not None:
            return GramSystem(None, b, system.yy.copy(), system.n_pixels, self.codes,
                              dense=dense_gram.sandwich(system.dense, M))
        G = [sandwich(g, m) for g, m in zip(system.G, M)]           # Mᵀ G M from G's triangle
        return GramSystem(G, b, system.yy.copy(), system.n_pixels, self.codes)

    def view(self, coeffs):
        """A view's per-pixel coefficients (``blocks()`` of :class:`ViewCoefficients`) mapped to
        the free monomials, ``A M_c`` block by block (a tiled view's blocks stay loaded one at a
        time)."""
        return _MappedView(coeffs, self)

    def block(self, block: ViewCoefficients) -> ViewCoefficients:
        rows = self._rows(block.codes)
        maps = [self.matrix(c, rows) for c in range(len(block.a))]
        mapped = lambda mats: None if mats is None else [sp.csr_matrix(m @ M) for m, M in zip(mats, maps)]
        return ViewCoefficients(mapped(block.a), mapped(block.b), block.split, self.codes)

    def reduce(self, x: np.ndarray) -> np.ndarray:
        """``(F, C)`` solver coordinates ``z = ρ_free / scale`` of a ``(P, C)`` ρ, in ``[0, 1]``."""
        x = np.asarray(x, dtype=float).reshape(len(self.values), -1)[self.free]
        return np.clip(np.divide(x, self.scale, out=np.zeros_like(x), where=self.scale > 0), 0.0, 1.0)

    def expand(self, z: np.ndarray, known: float | None = None) -> np.ndarray:
        """``(P, C)`` from the free parameters' ``(F, C)`` ``z``: ``scale · z`` there, the known
        values (or ``known``) at the others."""
        out = np.array(self.values) if known is None else np.full(self.values.shape, float(known))
        out[self.free] = self.scale * np.asarray(z, dtype=float)
        return out

    def _rows(self, codes: np.ndarray) -> np.ndarray:
        rows = np.searchsorted(self.old_codes, codes)
        if len(codes) and (rows.max() >= len(self.old_codes) or np.any(self.old_codes[rows] != codes)):
            raise ValueError("codes outside the substitution's monomials")
        return rows


class _MappedView:
    """:meth:`Substitution.view`: ``n_rows`` and ``blocks()`` as the fit's consumers iterate them.

    A consumer that only multiplies the coefficients by something over the free monomials (the
    values ``μ`` of a prediction, the Jacobian ``J`` of a score) can skip the mapping of every
    block: ``(A M_c) x = A (M_c x)``, with :meth:`lift` giving each ``M_c x`` over the view's own
    monomials :attr:`old_codes` and :attr:`coeffs` its own coefficients (bundled
    urban_canyon_survey, 2026-12-05: the blocks' mapping took 7.8 s of a 102 s solve, for the
    clusters' residuals and the sandwich's scores).
    """

    def __init__(self, coeffs, substitution: Substitution):
        self.coeffs, self.substitution = coeffs, substitution
        self.n_rows = coeffs.n_rows

    def blocks(self):
        for start, block in self.coeffs.blocks():
            yield start, self.substitution.block(block)

    @property
    def old_codes(self) -> np.ndarray:
        """The monomials of :attr:`coeffs` (those of the substitution's ``old_codes``)."""
        return self.substitution.old_codes

    def lift(self, xs, codes: np.ndarray) -> list:
        """``[M_c x_c]`` over :attr:`old_codes` for the channels' ``xs`` (arrays or sparse
        matrices, rows over the sorted free monomials ``codes``, which hold the substitution's
        ``codes``)."""
        at = np.searchsorted(codes, self.substitution.codes)
        return [self.substitution.matrix(c) @ x[at] for c, x in enumerate(xs)]
