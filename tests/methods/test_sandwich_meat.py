"""score_meat's dense scores (few parameters) and sparse ones (many) give the same meat."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.coefficients import TiledCoefficients, ViewCoefficients
from methods.symbolic.trace.monomial_codes import all_codes
from methods.symbolic.system import pixel_matrices
from methods.symbolic.uncertainty.sandwich_meat import score_meat

P, DEGREE, C, ROWS = 4, 2, 2, 120


def _views(rng):
    """Two views of random sparse half-sample coefficients (the second in two row blocks), their
    pixels, weights, clusters, owners and pose sensitivities."""
    codes = all_codes(P, DEGREE)
    views, extras = [], []
    for v in range(2):
        def half():
            return [sp.random(ROWS, len(codes), density=0.2, format="csr", random_state=rng) for _ in range(C)]
        a, b = half(), half()
        block = ViewCoefficients(a, b, 0.5, codes)
        coeffs = block if v == 0 else TiledCoefficients(
            [0, 50], [ViewCoefficients([m[:50] for m in a], [m[:50] for m in b], 0.5, codes),
                      ViewCoefficients([m[50:] for m in a], [m[50:] for m in b], 0.5, codes)], ROWS)
        views.append((coeffs, rng.uniform(0, 1, (ROWS, C)), rng.uniform(0.2, 1.0, ROWS)))
        extras.append((rng.integers(0, 9, ROWS), sp.csr_matrix(rng.uniform(size=(ROWS, P)) < 0.6, dtype=float),
                       (rng.normal(size=(ROWS, C, 2)), np.diag([0.3, 0.1]))))
    return MonomialBasis(P, DEGREE, codes), codes, views, extras


@pytest.mark.parametrize("options", ["plain", "clusters", "owned", "poses"])
def test_dense_and_sparse_scores_give_the_same_meat(monkeypatch, options):
    """The meat with the scores dense (``DENSE_JACOBIAN_COLUMNS`` at or above D) and sparse (below), halves and pixel
    weights throughout, with each of the clusters, the owners and the pose terms: equal to 1e-12
    of its largest entry (sums of the same products, in another order)."""
    rng = np.random.default_rng(11)
    basis, codes, views, extras = _views(rng)
    rho = rng.uniform(0.1, 0.6, (P, C))
    kwargs = {"plain": {}, "clusters": {"clusters": [e[0] for e in extras]},
              "owned": {"owned": [e[1] for e in extras]}, "poses": {"poses": [e[2] for e in extras]}}[options]
    meats = []
    for bound in (P, 0):
        monkeypatch.setattr(pixel_matrices, "DENSE_JACOBIAN_COLUMNS", bound)
        meats.append(score_meat(basis, rho, views, np.arange(len(codes)), codes, **kwargs))
    assert np.abs(meats[0]).max() > 0
    np.testing.assert_allclose(meats[0], meats[1], rtol=0, atol=1e-12 * np.abs(meats[0]).max())


@pytest.mark.parametrize("options", ["plain", "clusters", "owned", "poses", "no halves"])
def test_device_and_host_products_give_the_same_meat(options):
    """The meat with the scores' products formed on the device (the tests' ``llvm_ad_rgb``) and on
    the host, halves (but for ``no halves``) and pixel weights throughout, with each of the
    clusters, the owners and the pose terms: equal to 1e-12 of its largest entry (the products are the same sums in the same
    order, tests/methods/test_device_products.py; the same bits on the CPU this was written on)."""
    rng = np.random.default_rng(12)
    basis, codes, views, extras = _views(rng)
    rho = rng.uniform(0.1, 0.6, (P, C))
    kwargs = {"clusters": {"clusters": [e[0] for e in extras]}, "owned": {"owned": [e[1] for e in extras]},
              "poses": {"poses": [e[2] for e in extras]}}.get(options, {})
    if options == "no halves":
        views = [(ViewCoefficients(coeffs.a, None, 1.0, codes) if isinstance(coeffs, ViewCoefficients)
                  else TiledCoefficients([0, 50], [ViewCoefficients(b.a, None, 1.0, codes) for _, b in coeffs.blocks()],
                                         ROWS), y, w) for coeffs, y, w in views]
    host, device = (score_meat(basis, rho, views, np.arange(len(codes)), codes, device=d, **kwargs)
                    for d in (False, True))
    assert np.abs(host).max() > 0
    np.testing.assert_allclose(device, host, rtol=0, atol=1e-12 * np.abs(host).max())

