"""Normal equations of the least-squares cost (paper eq. 6, p = 2) in the monomial basis.

With the pixel polynomials ``L_i(ρ) = γ_i · μ(ρ)`` (eq. 8; ``μ(ρ)`` the vector of monomials) and
observed pixels ``y_i``, the cost of one channel is

    ε²(ρ) = Σ_i (γ_i·μ - y_i)² = μᵀ G μ - 2 bᵀ μ + yy,   G = Σ_i γ_i γ_iᵀ,  b = Σ_i y_i γ_i,  yy = Σ_i y_i²

so the pixels are summed once; the solver never touches them again and memory does not depend
on the pixel count.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp


@dataclass
class GramSystem:
    """Per-channel Gram system ``(G, b, yy)`` of the cost ``μᵀGμ - 2bᵀμ + yy``.

    Attributes
    ----------
    G : numpy.ndarray
        ``(C, N_e, N_e)`` float64, ``Σ_i γ_i γ_iᵀ`` per channel.
    b : numpy.ndarray
        ``(C, N_e)`` float64, ``Σ_i y_i γ_i``.
    yy : numpy.ndarray
        ``(C,)`` float64, ``Σ_i y_i²``.
    n_pixels : int
        Number of pixels accumulated.
    """

    G: np.ndarray
    b: np.ndarray
    yy: np.ndarray
    n_pixels: int = 0

    @classmethod
    def zeros(cls, n_monomials: int, n_channels: int) -> "GramSystem":
        """An empty system (no pixel)."""
        return cls(np.zeros((n_channels, n_monomials, n_monomials)),
                   np.zeros((n_channels, n_monomials)), np.zeros(n_channels), 0)

    @property
    def n_monomials(self) -> int:
        return self.G.shape[1]

    @property
    def n_channels(self) -> int:
        return self.G.shape[0]

    def accumulate(self, coeffs: np.ndarray, observed: np.ndarray, mask: np.ndarray | None = None, *,
                   coeffs_b: np.ndarray | None = None) -> "GramSystem":
        """Add pixels in place (returns ``self``).

        With ``coeffs_b``, an independent estimate of the same coefficients (the other half of
        the samples), ``G`` gets the symmetrised cross product ½(AᵀB + BᵀA) and ``b`` the mean
        ½(A + B)ᵀy. Since E[AᵀB] = ΓᵀΓ for independent halves, this G has no Monte Carlo noise
        term (E[AᵀA] = ΓᵀΓ + Σ Cov(γ_i), which shrinks the estimates: regression dilution).

        Parameters
        ----------
        coeffs : numpy.ndarray
            ``(n, N_e, C)`` polynomial coefficients of ``n`` pixels
            (:meth:`PolynomialPathIntegrator.coefficients`).
        observed : numpy.ndarray
            ``(n, C)`` observed radiance of the same pixels.
        mask : numpy.ndarray, optional
            ``(n,)`` bool, pixels to use (default all).

        Notes
        -----
        The coefficient matrix is 2-6 % non-zero, so ``G`` is built as a scipy.sparse CSR product
        ``ΓᵀΓ`` (float64), never a dense sum over pixels.
        """
        coeffs = np.asarray(coeffs)
        observed = np.asarray(observed, dtype=np.float64).reshape(coeffs.shape[0], -1)
        n, N_e, C = coeffs.shape
        if N_e != self.n_monomials or C != self.n_channels:
            raise ValueError(f"coeffs shape {coeffs.shape} does not match the system "
                             f"(N_e={self.n_monomials}, C={self.n_channels})")
        if observed.shape[1] != C:
            raise ValueError(f"observed has {observed.shape[1]} channels, expected {C}")
        if mask is not None:
            mask = np.asarray(mask, bool).reshape(n)
            coeffs, observed = coeffs[mask], observed[mask]
            n = coeffs.shape[0]
        if coeffs_b is not None:
            coeffs_b = np.asarray(coeffs_b)
            if coeffs_b.shape[1:] != coeffs.shape[1:] or (mask is None and len(coeffs_b) != len(coeffs)):
                raise ValueError(f"coeffs_b shape {coeffs_b.shape} does not match coeffs {coeffs.shape}")
            if mask is not None:
                coeffs_b = coeffs_b[mask]
        as_csr = lambda g: [sp.csr_matrix(np.asarray(g[:, :, c], dtype=np.float64)) for c in range(C)]
        return self.accumulate_sparse(as_csr(coeffs), observed, as_csr(coeffs_b) if coeffs_b is not None else None)

    def accumulate_sparse(self, A: list, observed: np.ndarray, B: list | None = None) -> "GramSystem":
        """:meth:`accumulate` for coefficients given as one sparse ``(n, N_e)`` matrix per channel
        (``A``, and the independent half ``B``), as :meth:`PolynomialPathIntegrator.coefficients_sparse`
        returns them."""
        observed = np.asarray(observed, dtype=np.float64).reshape(A[0].shape[0], -1)
        n = A[0].shape[0]
        for c in range(self.n_channels):
            y = observed[:, c]
            if B is None:
                self.G[c] += (A[c].T @ A[c]).toarray()
                self.b[c] += A[c].T @ y
            else:
                AB = (A[c].T @ B[c]).toarray()
                self.G[c] += 0.5 * (AB + AB.T)
                self.b[c] += 0.5 * (A[c].T @ y + B[c].T @ y)
            self.yy[c] += float(y @ y)
        self.n_pixels += n
        return self

    def psd(self) -> "GramSystem":
        """This system with each ``G_c`` projected onto the positive semi-definite matrices
        (negative eigenvalues set to 0, on the monomials in use).

        The cross Gram ½(AᵀB + BᵀA) is unbiased but, being a difference of noisy products, not
        PSD: along directions the pixels barely constrain, its negative eigenvalues let the cost
        decrease without bound and the solve runs to the constraints. ΓᵀΓ is PSD, and the
        projection onto that convex set moves the estimate closer to it in Frobenius norm.
        """
        used = self.used_monomials()
        G = self.G.copy()
        for c in range(self.n_channels):
            sub = G[c][np.ix_(used, used)]
            w, V = np.linalg.eigh(0.5 * (sub + sub.T))
            G[c][np.ix_(used, used)] = (V * np.maximum(w, 0.0)) @ V.T
        return GramSystem(G, self.b.copy(), self.yy.copy(), self.n_pixels)

    def used_monomials(self) -> np.ndarray:
        """Indices of the monomials some pixel depends on (a non-zero row of G or entry of b, any
        channel). The others do not change the cost: a solver may leave them out (a single street
        view holds about 40 % of the N_e monomials)."""
        return np.flatnonzero(np.any(self.G != 0, axis=(0, 2)) | np.any(self.b != 0, axis=0))

    def __add__(self, other: "GramSystem") -> "GramSystem":
        if not isinstance(other, GramSystem):
            return NotImplemented
        if other.G.shape != self.G.shape:
            raise ValueError(f"cannot add systems of shapes {self.G.shape} and {other.G.shape}")
        return GramSystem(self.G + other.G, self.b + other.b, self.yy + other.yy,
                          self.n_pixels + other.n_pixels)

    def cost(self, mu: np.ndarray) -> np.ndarray:
        """Per-channel sum of squared residuals ``μ_cᵀ G_c μ_c - 2 b_cᵀ μ_c + yy_c``.

        Parameters
        ----------
        mu : numpy.ndarray
            ``(C, N_e)`` monomial values per channel (``basis.evaluate(ρ[:, c])``).

        Returns
        -------
        numpy.ndarray
            ``(C,)`` costs (sum them for the total, eq. 6 squared with p = 2).
        """
        mu = np.asarray(mu, dtype=np.float64).reshape(self.n_channels, self.n_monomials)
        return (np.einsum("ci,cij,cj->c", mu, self.G, mu) - 2 * np.einsum("ci,ci->c", self.b, mu)
                + self.yy)
