"""The registered cameras' pose uncertainty in the std (``score_meat(poses=...)``,
:func:`methods.symbolic.misfit.alignment.pose_terms`): by hand, and its coverage on a view whose pose error
is drawn from the covariance the std is given.

The model: one weight ρ, pixels ``y_p = ρ a(x_p - δ) + e_p`` on a 64x64 view with a ramp and a
ripple ``a`` along x, seen by a model that takes the pose as exact (``Γ_p = a(x_p)``): the pose error
δ (pixels) moves the estimate by about ρ δ Σa a' / Σa², which no pixel's noise shows."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.coefficients import ViewCoefficients
from methods.symbolic.system.view_systems import weighted_system
from methods.symbolic.trace.monomial_codes import all_codes
from methods.symbolic.uncertainty.sandwich_meat import score_meat
from methods.symbolic.uncertainty.standard_errors import parameter_uncertainty

SIZE, TRUTH, SIGMA, POSE_STD = 64, 0.4, 0.02, 0.3


def _pattern(x: np.ndarray) -> np.ndarray:
    return 0.5 + x / SIZE + 0.2 * np.sin(x / 2.0)


def _view(seed: int):
    """``(coefficients, y, G, rho)``: the view, its pose sensitivity along x (the observation's
    gradient, as :func:`~methods.symbolic.misfit.registration.pose_sensitivity` takes it) and the
    least-squares estimate."""
    rng = np.random.default_rng(seed)
    x = np.tile(np.arange(SIZE) + 0.5, SIZE)
    delta = rng.normal(0.0, POSE_STD)
    y = (TRUTH * _pattern(x - delta) + rng.normal(0.0, SIGMA, x.size))[:, None]
    a = _pattern(x)
    codes = all_codes(1, 1)
    coeffs = ViewCoefficients([sp.csr_matrix(np.stack([np.zeros_like(a), a], axis=1))], None, 0.5, codes)
    G = np.gradient(y[:, 0].reshape(SIZE, SIZE), axis=1).reshape(-1, 1, 1)
    rho = np.array([[float(a @ y[:, 0] / (a @ a))]])
    return coeffs, y, G, rho, a


def _std(coeffs, y, rho, poses=None) -> float:
    codes = all_codes(1, 1)
    basis = MonomialBasis(1, 1, codes)
    meat = score_meat(basis, rho, [(coeffs, y)], np.arange(len(codes)), codes, poses=poses)
    return float(parameter_uncertainty(weighted_system(coeffs, y, None), basis, rho, meat=meat).std[0, 0])


def test_pose_term_by_hand():
    """One view, no halves: ∂s_p/∂r_p = 2 a_p (the cost's gradient term 2 a_p r_p), so the pose adds
    ``(Σ_p 2 a_p G_p)² σ_δ²`` to the meat; the Hessian is ``2 Σ a²``. A zero covariance adds nothing."""
    coeffs, y, G, rho, a = _view(0)
    plain = _std(coeffs, y, rho)
    assert _std(coeffs, y, rho, poses=[(G, np.zeros((1, 1)))]) == plain
    assert _std(coeffs, y, rho, poses=[None]) == plain
    T = float(np.sum(2.0 * a * G[:, 0, 0]))
    expected = np.sqrt(plain ** 2 + (T * POSE_STD) ** 2 / (2.0 * a @ a) ** 2)
    got = _std(coeffs, y, rho, poses=[(G, np.array([[POSE_STD ** 2]]))])
    assert got == pytest.approx(expected, rel=1e-9)


def test_pose_term_covers_the_pose_error():
    """Over 30 seeds (δ ~ N(0, 0.3 px), pixel noise 0.02): without the pose term the std is the
    pixels' noise only and the RMS of error/std is far above 1 (measured 5.45); with it, within
    [0.7, 1.5] (measured 0.96)."""
    z_plain, z_pose = [], []
    for seed in range(30):
        coeffs, y, G, rho, _ = _view(seed)
        error = rho[0, 0] - TRUTH
        z_plain.append(error / _std(coeffs, y, rho))
        z_pose.append(error / _std(coeffs, y, rho, poses=[(G, np.array([[POSE_STD ** 2]]))]))
    rms = lambda z: float(np.sqrt(np.mean(np.square(z))))  # noqa: E731
    assert rms(z_plain) > 3.0, rms(z_plain)
    assert 0.7 <= rms(z_pose) <= 1.5, rms(z_pose)
