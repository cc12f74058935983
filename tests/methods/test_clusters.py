"""The cluster-robust sandwich (methods/symbolic/misfit/clusters.py, ``method.std=cluster``): clusters,
the correlation length, the CR1 factor by hand, and its coverage on residuals of known spatial
correlation, where the pixel sandwich's std is too small."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.ndimage import uniform_filter

from methods.symbolic.misfit.clusters import CORRELATION_FLOOR, cluster_ids, correlation_length, cr1_factor, side_for
from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.coefficients import ViewCoefficients
from methods.symbolic.system.view_systems import weighted_system
from methods.symbolic.trace.monomial_codes import all_codes
from methods.symbolic.uncertainty.sandwich_meat import score_meat
from methods.symbolic.uncertainty.standard_errors import parameter_uncertainty

SIZE, TRUTH, SIGMA = 64, 0.4, 0.02


def test_cluster_ids_by_hand():
    seg = np.array([[0, 0, 1, 1],
                    [0, 0, 1, 1],
                    [0, 0, 0, 0],
                    [-1, -1, 0, 0]])
    ids = cluster_ids(seg, 2).reshape(4, 4)
    # squares of 2x2, split by segment: (0, top-left), (1, top-right), (0, bottom-right),
    # (0, bottom-left row 2) and (-1, bottom-left row 3) are five clusters
    assert len(np.unique(ids)) == 5
    assert ids[0, 0] == ids[1, 1] and ids[0, 2] == ids[1, 3] and ids[2, 2] == ids[3, 3]
    assert ids[2, 0] == ids[2, 1] != ids[3, 0] == ids[3, 1]
    assert cluster_ids(seg, 1).max() == 15


def test_cr1_factor_by_hand():
    assert cr1_factor(10, 101, 1) == pytest.approx(10 / 9 * 100 / 100)
    assert cr1_factor(4, 64, 3) == pytest.approx(4 / 3 * 63 / 61)
    assert cr1_factor(1, 64, 3) == 1.0


def _noise(rng, width: int) -> np.ndarray:
    """Gaussian noise of std SIGMA, averaged over ``width`` x ``width`` boxes (width 1: white):
    its autocorrelation at lag k < width is (1 - k/width)² along a diagonal, (1 - k/width) along
    an axis."""
    e = rng.normal(size=(SIZE, SIZE))
    if width > 1:
        e = uniform_filter(e, size=width, mode="wrap")
    return SIGMA * e / e.std()


def test_correlation_length_of_white_and_box_noise():
    """White noise: lag 1 (autocorrelation ~0 < 0.1); box-averaged over 4 pixels: the axis
    autocorrelation is 1 - k/4 (0.75, 0.5, 0.25, 0), so the floor 0.1 is passed at lag 4."""
    rng = np.random.default_rng(0)
    seg = np.zeros((SIZE, SIZE), int)
    white, profile = correlation_length([_noise(rng, 1)[..., None]], [seg], [None])
    assert white == 1 and abs(profile[0]) < CORRELATION_FLOOR
    box, profile = correlation_length([_noise(rng, 4)[..., None]], [seg], [None])
    assert box == 4 and profile[0] == pytest.approx(0.75, abs=0.06)
    assert side_for(box) == 8


def _fit(seed: int, width: int):
    """One linear pixel model y_p = ρ a_p + e_p (a_p in [0.5, 1.5], e of the given width), fitted by
    least squares through the symbolic machinery: ``(estimate, pixel std, cluster std, side)``."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(0.5, 1.5, SIZE * SIZE)
    y = (TRUTH * a + _noise(rng, width).ravel())[:, None]
    codes = all_codes(1, 1)
    basis = MonomialBasis(1, 1, codes)
    gamma = sp.csr_matrix(np.stack([np.zeros_like(a), a], axis=1))
    coeffs = ViewCoefficients([gamma], None, 0.5, codes)
    system = weighted_system(coeffs, y, None)
    rho = np.array([[float(a @ y[:, 0] / (a @ a))]])
    views = [(coeffs, y)]
    columns = np.arange(len(codes))
    pixel = parameter_uncertainty(system, basis, rho, meat=score_meat(basis, rho, views, columns, codes)).std
    residual = (gamma @ basis.evaluate(rho[:, 0]) - y[:, 0]).reshape(SIZE, SIZE, 1)
    seg = np.zeros((SIZE, SIZE), int)
    length, _ = correlation_length([residual], [seg], [None])
    ids = [cluster_ids(seg, side_for(length))]
    cluster = parameter_uncertainty(system, basis, rho, meat=score_meat(basis, rho, views, columns, codes,
                                                                        clusters=ids)).std
    return rho[0, 0], pixel[0, 0], cluster[0, 0], side_for(length)


@pytest.mark.parametrize("width", [4, 6])
def test_cluster_std_covers_correlated_errors(width):
    """Over 30 seeds of 64x64 residuals averaged over ``width``-pixel boxes: the pixel sandwich's
    z-scores have an RMS well above 1 (it counts each of the ~width² correlated pixels as
    independent: measured RMS 4.03 at width 4, 6.04 at width 6), the cluster sandwich's within
    [0.7, 1.5] (measured 1.25 and 1.37: squares of side 8, and 10-12, hold most but not all of
    each error's correlated neighbours)."""
    z_pixel, z_cluster = [], []
    for seed in range(30):
        est, pixel, cluster, side = _fit(seed, width)
        assert side >= width
        z_pixel.append((est - TRUTH) / pixel)
        z_cluster.append((est - TRUTH) / cluster)
    rms = lambda z: float(np.sqrt(np.mean(np.square(z))))  # noqa: E731
    assert rms(z_pixel) > 2.0, rms(z_pixel)
    assert 0.7 <= rms(z_cluster) <= 1.5, rms(z_cluster)


def test_cluster_std_agrees_with_the_pixel_std_on_white_noise():
    """Independent residuals: the clusters are 2x2 squares and the two stds agree within 20 % on
    every one of 10 seeds (measured 0.97-1.02 of each other)."""
    for seed in range(10):
        _, pixel, cluster, side = _fit(seed, 1)
        assert side == 2
        assert 0.8 <= cluster / pixel <= 1.2, (seed, cluster / pixel)


def test_cluster_std_in_a_run(tmp_path):
    """``method.std=cluster`` on the tiny scene (2 views of 16x16, synthetic observations: no
    misfit beyond Monte Carlo noise): results name the formula and the clusters (side 2: the
    residuals' lag-1 autocorrelation is about 0), the estimates are the sandwich run's, and each
    std is within a factor 2 of the pixel sandwich's (measured over seeds 0-2: 0.62-1.09; the
    block's few dozen clusters make its cluster estimate the noisier one, 0.62-0.98)."""
    from factory import run_symbolic, tiny_problem

    problem = tiny_problem(tmp_path / "s", n_views=2, spp=16, obs_spp=64)
    pixel = run_symbolic(problem, std="sandwich", refine=0)
    cluster = run_symbolic(problem, std="cluster", refine=0)
    assert cluster.extras["std_method"] == "cluster"
    about = cluster.extras["std_clusters"]
    assert 1 <= about["side"] <= 32 and len(about["autocorrelation"]) == about["correlation_length"]
    np.testing.assert_array_equal(cluster.estimate, pixel.estimate)
    ratio = cluster.std / pixel.std
    assert np.all((0.5 <= ratio) & (ratio <= 2.0)), ratio


def test_std_device_in_a_run(tmp_path, monkeypatch):
    """``method.std_device=device`` against ``host`` on the tiny scene, cluster and pixel sandwich:
    the device forms the products (and only with ``device``), the same estimates, and the same std
    to 1e-10 (the scores' products are the same sums in the same order,
    tests/methods/test_device_products.py; equal to the bit on the CPU this was written on)."""
    from factory import run_symbolic, tiny_problem
    from methods.symbolic.uncertainty import sandwich_meat

    launched = []

    def counted(pairs):
        launched.append(len(pairs))
        return device_products(pairs)

    device_products = sandwich_meat.device_products
    monkeypatch.setattr(sandwich_meat, "device_products", counted)
    problem = tiny_problem(tmp_path / "s", n_views=2, spp=16, obs_spp=64)
    for std in ("cluster", "sandwich"):
        host = run_symbolic(problem, std=std, refine=0, std_device="host")
        assert not launched
        device = run_symbolic(problem, std=std, refine=0, std_device="device")
        assert launched
        launched.clear()
        np.testing.assert_array_equal(device.estimate, host.estimate)
        assert np.all(np.isfinite(host.std))
        np.testing.assert_allclose(device.std, host.std, rtol=1e-10)
