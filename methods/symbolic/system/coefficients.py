"""A view's per-pixel coefficients as the polynomial pass keeps them, and the pass's result.

Each pixel's coefficients are sparse rows over the monomials that occur (2-6 % non-zero), as the
two independent estimates from the two halves of its samples (:class:`ViewCoefficients`): their
cross product is the unbiased Gram matrix, their mean the coefficients, their difference the
per-pixel Monte Carlo noise the sandwich standard errors need. A view is a list of row blocks
(the pass's tiles, :class:`TiledCoefficients`), each held or loaded from the cache when iterated.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from methods.symbolic.system.gram import GramSystem
from methods.symbolic.system.view_systems import summed, weighted_system


@dataclass
class ViewCoefficients:
    """A view's per-pixel coefficients, one sparse ``(pixels, len(codes))`` float64 matrix per
    channel, over the monomial ``codes`` that occur in the view (its system's codes).

    ``a``, ``b``: the two independent estimates of the coefficients from the two halves of each
    pixel's samples (each a full estimate; ``a`` holds the fraction ``split`` of the samples, 1/2
    at even spp), kept as the pass made them: the cross Gram is ½(AᵀB + BᵀA) and the estimate
    from all samples (eq. 8) is Γ = split·A + (1 - split)·B (:meth:`apply`). ``b`` is None when
    the pass had no halves (``gram=plain`` or spp < 2): ``a`` is then Γ.

    ``a1``, ``b1``: with ``method.bias=richardson``, the estimates from the first half of ``a``'s
    and of ``b``'s samples (``split`` 1/2); the four quarters ``a1``, ``2a - a1``, ``b1``,
    ``2b - b1`` are independent, and :meth:`halved` pairs them into the coefficients of a pass
    with half the samples.

    ``factors``: how ``a`` and ``b`` were expanded by per-pixel factors
    (:class:`~methods.symbolic.system.row_factors.RowFactors`, a lens to estimate), from which their
    Gram matrix is formed at a fraction of the cost; None otherwise.
    """

    a: list
    b: list | None = None
    split: float = 0.5
    codes: np.ndarray | None = None
    a1: list | None = None
    b1: list | None = None
    factors: object | None = None

    @property
    def n_rows(self) -> int:
        return self.a[0].shape[0]

    def apply(self, c: int, x: np.ndarray) -> np.ndarray:
        """``Γ_c x`` for channel ``c`` (x over this block's ``codes``), without forming Γ."""
        if self.b is None:
            return self.a[c] @ x
        return self.split * (self.a[c] @ x) + (1.0 - self.split) * (self.b[c] @ x)

    def blocks(self):
        """``(first row, ViewCoefficients)`` of each row block: itself, from row 0."""
        yield 0, self

    @property
    def held(self) -> bool:
        """Whether every block is in memory (not read from the cache when iterated): yes."""
        return True

    def halved(self, j: int) -> ViewCoefficients:
        """The coefficients of half the samples, as a pass with half the spp keeps them: the
        quarters of ``a`` (``j`` 0) or of ``b`` (``j`` 1) as its two independent halves."""
        first, whole = (self.a1, self.a) if j == 0 else (self.b1, self.b)
        if first is None:
            raise ValueError("these coefficients have no quarters: render with method.bias=richardson")
        return ViewCoefficients(first, [2.0 * w - f for f, w in zip(first, whole)], 0.5, self.codes)


class TiledCoefficients:
    """A view's coefficients as row blocks (the pass's tiles), each a :class:`ViewCoefficients`
    over the monomials of its own pixels; a block is held, or a function loading it (from the
    cache): iterating :meth:`blocks` then holds one block at a time, so a megapixel view's
    coefficients never need to fit in memory at once.

    Consumers (:func:`predicted`, :func:`~methods.symbolic.system.view_systems.weighted_system`,
    :func:`~methods.symbolic.uncertainty.sandwich_meat.score_meat`) iterate :meth:`blocks` of either class.
    """

    def __init__(self, starts, blocks: list, n_rows: int):
        self.starts = [int(s) for s in starts]
        self._blocks = list(blocks)
        self.n_rows = int(n_rows)

    def blocks(self):
        for start, block in zip(self.starts, self._blocks):
            yield start, (block() if callable(block) else block)

    @property
    def held(self) -> bool:
        """Whether every block is in memory, none read from the cache when iterated."""
        return not any(callable(block) for block in self._blocks)

    def halved(self, j: int) -> TiledCoefficients:
        """:meth:`ViewCoefficients.halved` of every block, made as each block is read."""
        return TiledCoefficients(self.starts, [_Halved(block, j) for block in self._blocks], self.n_rows)


@dataclass(frozen=True)
class _Halved:
    """A block's :meth:`ViewCoefficients.halved` when called (a cached block is read then)."""

    block: object
    j: int

    def __call__(self) -> ViewCoefficients:
        block = self.block
        if hasattr(block, "with_quarters"):      # read from the cache: a plain read leaves them out
            block = block.with_quarters()
        block = block() if callable(block) else block
        return block.halved(self.j)


@dataclass
class PassResult:
    """The pass over all views: their summed Gram system, and each view's coefficients.

    ``views[name]`` is the view's :class:`TiledCoefficients`; with a cache its blocks wait on
    disk (:class:`TileLoader`): memory then stays flat in the number of views and in their size. The views' own Gram
    systems are consumed by the sum.
    """

    system: GramSystem | None                            # summed over views as a tree, in view order
    views: dict[str, object]
    render_s: float = 0.0
    from_cache: list[str] = field(default_factory=list)  # views read from the cache
    codes: np.ndarray | None = None                      # the monomials of the pass (the system's)

    def __post_init__(self):
        if self.codes is None:
            self.codes = self.system.codes

    def coefficients(self, name: str) -> TiledCoefficients:
        return self.views[name]

    def take_system(self) -> GramSystem:
        """The summed Gram system, handed over: this result keeps its ``codes`` only, so the
        solve can release the system's memory (hundreds of MB on a long street) as it restricts
        and projects it, and a refinement pass does not render with it still held."""
        system, self.system = self.system, None
        if system is None:
            raise RuntimeError("the pass's Gram system was already taken")
        return system

    def halved(self, j: int, observed: dict, *, system: bool = True) -> PassResult:
        """The pass with half the samples (``j`` 0: the quarters of each pixel's first half,
        1: of its second; :meth:`ViewCoefficients.halved`), its Gram system summed from them
        as a cached view's is (:func:`~methods.symbolic.system.view_systems.weighted_system`); ``observed``:
        view -> observed image. ``system`` False: no system (a fit that forms its own weighted
        systems, the field path, would only release it); its ``codes`` are this pass's, which
        the halves' summed system would have (each block keeps its codes)."""
        views = {name: coeffs.halved(j) for name, coeffs in self.views.items()}
        if not system:
            return PassResult(None, views, codes=self.codes)
        system = None
        for name, coeffs in views.items():
            y = np.asarray(observed[name]).reshape(coeffs.n_rows, -1)
            system = summed(system, weighted_system(coeffs, y, None))
        return PassResult(system, views)

    def image(self, view: str, mu: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """The polynomial image of ``view`` at monomials ``mu`` (C, N) over ``codes``:
        (H, W, C) float32."""
        pixels = predicted(self.coefficients(view), mu, self.codes)
        return pixels.reshape(*shape, len(mu)).astype(np.float32)


def predicted(coeffs, mu: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """``(n, C)`` pixel values of a view's coefficients (:class:`ViewCoefficients` or
    :class:`TiledCoefficients`, Γ over each block's ``codes``) at monomials ``mu``
    (C, N) over the sorted ``codes``, a superset of the view's. Coefficients mapped to fewer
    monomials that can ``lift`` ``μ`` to their own (a known weight substituted,
    :class:`~methods.symbolic.survey.known.Substitution`) are evaluated through their own
    coefficients, not mapped block by block."""
    if hasattr(coeffs, "lift"):
        return predicted(coeffs.coeffs, np.stack(coeffs.lift(mu, codes)), coeffs.old_codes)
    out = []
    for _, block in coeffs.blocks():
        at = np.searchsorted(codes, block.codes)
        out.append(np.stack([block.apply(c, mu[c][at]) for c in range(len(block.a))], axis=1))
    return np.concatenate(out)


def predicted_with_variance(coeffs, mu: np.ndarray, codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(n, C)`` :func:`predicted` values and their Monte Carlo variance, in one sweep over the
    blocks (a cached view's tiles are read once). The variance is one estimate per pixel from its
    two half-sample estimates: ``Γ = s A + (1 - s) B`` with ``A``, ``B`` independent, so
    ``Var(Γμ) = s (1 - s) E[((A - B) μ)²]`` (``s`` = ``split``; zeros without halves).
    Single-pixel and so itself noisy (one degree of freedom); it tells the pixels whose pass drew
    a rare, bright path (which an unbiased estimate needs) from those whose observation departs
    from any prediction."""
    values, variances = [], []
    for _, block in coeffs.blocks():
        at = np.searchsorted(codes, block.codes)
        C = len(block.a)
        if block.b is None:
            values.append(np.stack([block.a[c] @ mu[c][at] for c in range(C)], axis=1))
            variances.append(np.zeros_like(values[-1]))
            continue
        a = np.stack([block.a[c] @ mu[c][at] for c in range(C)], axis=1)
        b = np.stack([block.b[c] @ mu[c][at] for c in range(C)], axis=1)
        values.append(block.split * a + (1.0 - block.split) * b)
        variances.append(block.split * (1.0 - block.split) * (a - b) ** 2)
    return np.concatenate(values), np.concatenate(variances)


def images_with_variance(views, mu: np.ndarray, codes: np.ndarray) -> tuple[dict, dict]:
    """Each view's polynomial image at monomials ``mu`` (C, N) over ``codes`` and each pixel's
    Monte Carlo variance (:func:`predicted_with_variance`), both ``(H, W, C)`` float32 by view
    name; ``views``: ``(name, coefficients, (H, W))`` triples."""
    images, variances = {}, {}
    for name, coeffs, shape in views:
        value, var = predicted_with_variance(coeffs, mu, codes)
        images[name] = value.reshape(*shape, -1).astype(np.float32)
        variances[name] = var.reshape(*shape, -1).astype(np.float32)
    return images, variances
