"""Every registered method renders the scene it claims: at the reference weights, the image its
own forward model produces (:meth:`framework.registry.Method.render_at`) equals Mitsuba's
``path`` image of the same scene, within Monte Carlo error, on segments with two kernels.

The reference is ``path`` with ``max_depth = N_max + 1`` (every method traces N_max reflections),
at the weights of the kernels the method models (the Lambertian prior models no mirror, so its
reference scene has ρ_s = 0). Per segment and channel, the means of 4 independent renders of
each side differ by at most 4 standard errors (SE from the repetitions' sample variances); the
differentiable baseline's ``render_at`` is its AD integrator's primal pass.
"""
from __future__ import annotations

import numpy as np
import pytest

from factory import make_problem, make_tiny_scene, mean_difference, method_config
from framework.registry import available_methods, get_method
from framework.render.mitsuba_scene import MitsubaScene, max_depth_for

REPS = 4


@pytest.fixture(scope="module")
def two_kernel_problem(tmp_path_factory):
    root = make_tiny_scene(tmp_path_factory.mktemp("s") / "tiny", kernels=("diffuse", "specular"), size=24)
    return make_problem(root, None, "render.spp=32", "render.max_bounces=3")


def _reference_images(problem, params, rho, view: int) -> list[np.ndarray]:
    """``path`` renders of ``view`` at ρ, the kernels outside ``params`` at 0."""
    ms = MitsubaScene(problem.scene, problem.cameras, spp=32,
                      integrator={"type": "path", "max_depth": max_depth_for(problem.settings.max_bounces)})
    full = {(p.segment, p.kernel): p.index for p in problem.parameters}
    ms.set_weights(rho[[full[(p.segment, p.kernel)] for p in params]], params)
    return [ms.render(view, spp=32, seed=2 * k + 1) for k in range(REPS)]


@pytest.mark.parametrize("name", available_methods())
def test_method_renders_the_reference_scene(two_kernel_problem, name):
    problem = two_kernel_problem
    method = get_method(name)(method_config(name))
    params = method.parameters(problem)
    assert {p.kernel for p in problem.parameters} == {"diffuse", "specular"}
    rho = problem.scene.reference(problem.parameters)
    ours = [method.render_at(problem, rho, seed=100 + k) for k in range(REPS)]
    ms = MitsubaScene(problem.scene, problem.cameras, spp=1)
    for v, cam in enumerate(problem.cameras):
        seg = ms.segment_map(v)
        ref = _reference_images(problem, params, rho, v)
        for s in np.unique(seg):
            a = np.array([img[seg == s].mean(axis=0) for img in ref])
            b = np.array([imgs[cam.name][seg == s].mean(axis=0) for imgs in ours])
            diff, se = mean_difference(a, b)
            assert np.all(np.abs(diff) <= 4 * se + 1e-5), (name, cam.name, int(s), a.mean(0), b.mean(0), se)
