"""The heteroscedastic robust scale (methods/symbolic/misfit/robust_scale.py)."""
import numpy as np

from methods.symbolic.misfit.robust_scale import robust_scale


def test_plain_scale_is_the_mad_about_zero():
    """Without variances: median |d| / 0.6745 (hand value: |d| = 1, 2, 3 -> 2 / 0.6745)."""
    np.testing.assert_allclose(robust_scale(np.array([[1.0], [-2.0], [3.0]])), [2.0 / 0.6744897501960817])


def test_scale_recovers_the_shared_part():
    """d_p ~ N(0, s² + v_p) with s = 0.5 and v_p spread over two decades: the scale is s within
    5 % (n = 20000: the MAD's relative std is about 1.1/sqrt(n) ~ 0.8 %), where the plain MAD would
    be about twice s; and variances that explain everything give 0."""
    rng = np.random.default_rng(0)
    v = rng.uniform(0.01, 1.0, (20000, 2))
    d = rng.normal(0.0, np.sqrt(0.25 + v))
    s = robust_scale(d, v)
    np.testing.assert_allclose(s, 0.5, rtol=0.05)
    assert np.all(robust_scale(d) > 1.5 * s)
    np.testing.assert_allclose(robust_scale(0.1 * d, v), 0.0, atol=1e-12)
