"""The forward BSDF of a segment equals Σ_i ρ_i f_i (paper eq. 4), channel by channel."""
from __future__ import annotations

import numpy as np
import pytest
from factory import mean_and_se

from framework import brdf_kernels as K
from framework.render import kernel_bsdf as KB


def _bsdf(kernels, rho):
    import mitsuba as mi
    b = mi.load_dict(KB.forward_bsdf(kernels, ("R", "G", "B")))
    p = mi.traverse(b)
    for key, v in zip(KB.weight_keys(kernels), np.asarray(rho, float).reshape(len(kernels), -1)):
        p[key] = mi.Color3f(*[float(x) for x in v])
    p.update()
    return b


def _si(n, wi):
    import drjit as dr
    import mitsuba as mi
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*[float(x) for x in wi])
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.n = mi.Vector3f(0, 0, 1)
    return si


RHO = np.array([[0.72, 0.5, 0.3], [0.08, 0.2, 0.6]])   # ρ_d, ρ_s per channel; ρ_d + ρ_s can exceed... <= 1 here


def test_forward_bsdf_eval_is_diffuse_part():
    """eval() of the smooth part: ρ_d/π · cos θ_o, by hand, on both sides of the surface."""
    import mitsuba as mi
    b = _bsdf(["diffuse", "specular"], RHO)
    wo = np.array([0.3, 0.0, np.sqrt(1 - 0.09)])
    for sign in (1, -1):
        v = np.array(b.eval(mi.BSDFContext(), _si(1, [0, 0.6 * sign, 0.8 * sign]),
                            mi.Vector3f(*(wo * [1, 1, sign]).tolist()))).ravel()
        np.testing.assert_allclose(v, RHO[0] / np.pi * wo[2], rtol=1e-5)


def test_forward_bsdf_white_furnace_albedo():
    """Directional albedo ∫ f cos dω = ρ_d + ρ_s (energy of a Lambertian + mirror kernel BRDF).

    Monte Carlo over 2^18 BSDF samples; tolerance 5 standard errors of the sample mean.
    """
    import mitsuba as mi
    b = _bsdf(["diffuse", "specular"], RHO)
    n = 1 << 18
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(3, n)
    _, w = b.sample(mi.BSDFContext(), _si(n, [0.0, 0.6, 0.8]), sampler.next_1d(), sampler.next_2d())
    mean, se = mean_and_se(np.array(w).T)
    np.testing.assert_allclose(mean, RHO.sum(0), atol=5 * se.max() + 1e-6)


def test_kernel_errors():
    from framework.errors import SceneError
    with pytest.raises(SceneError, match="unknown kernel 'glossy'"):
        K.get("glossy")
