"""Unknown emitter scales in the symbolic fit (methods/symbolic/survey/illumination.py; issue 26 item 1).

The scene tests photograph the tiny diffuse scene (32 x 32 pixels, 3 views, observations at
256 spp, polynomial pass at 16 spp, seed 0) under a light that differs from the declared one:
the sun 15 % brighter, or the sun 15 % brighter and the sky 15 % dimmer. Measured numbers are
in each test's docstring.
"""
import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from factory import method_config, run_symbolic
from framework.errors import ConfigError
from framework.scene.model import Emitter
from methods.symbolic import SymbolicMethod
from methods.symbolic.survey.illumination import SCALE_MAX, Illumination, check_gauge

SUN, SKY = 1.15, 0.85               # true / declared


def _lit(scene, sun: float, sky: float):
    """``scene`` with its constant sky's radiance times ``sky`` and its sun's irradiance times ``sun``."""
    sky_e, sun_e = scene.emitters
    return dataclasses.replace(scene, emitters=[dataclasses.replace(sky_e, radiance=sky_e.radiance * sky),
                                                dataclasses.replace(sun_e, irradiance=sun_e.irradiance * sun)])


def _declared(problem, *, sun_unknown: bool, sky_unknown: bool, known_ground: bool = False):
    """The problem with the emitters as declared (nominal) and their scales marked unknown."""
    scene = problem.scene
    sky_e, sun_e = scene.emitters
    emitters = [dataclasses.replace(sky_e, scale_unknown=sky_unknown), dataclasses.replace(sun_e, scale_unknown=sun_unknown)]
    segments = list(scene.segments)
    params = list(problem.parameters)
    if known_ground:
        segments[0] = dataclasses.replace(segments[0], known={"diffuse": segments[0].reference["diffuse"]})
    scene = dataclasses.replace(scene, emitters=emitters, segments=segments)
    return dataclasses.replace(problem, scene=scene, parameters=params)


@pytest.fixture(scope="module")
def photographed(tmp_path_factory):
    """``(problem declaring the nominal light, observations under sun x 1.15 only, under sun x 1.15
    and sky x 0.85, reference ρ)``."""
    from factory import make_tiny_scene
    from framework.config import RunSettings
    from framework.observe import render_references
    from framework.registry import Problem
    from framework.scene import load_scene
    scene = load_scene(make_tiny_scene(tmp_path_factory.mktemp("light") / "s", size=32, n_views=3,
                                       kernels=("diffuse",)))
    cams = list(scene.cameras)
    sun_only = render_references(_lit(scene, SUN, 1.0), cams, spp=256, max_depth=4, seed=1)
    both = render_references(_lit(scene, SUN, SKY), cams, spp=256, max_depth=4, seed=1)
    settings = RunSettings(spp=16, max_bounces=3, budget_renders=100, seed=0, cache_dir=None)
    problem = Problem(scene=scene, cameras=cams, observed={c.name: o for c, o in zip(cams, sun_only)},
                      parameters=scene.parameters(), settings=settings)
    return problem, {c.name: o for c, o in zip(cams, both)}, scene.reference(scene.parameters())


def _within(estimate, target, std, what, slack=0.005):
    """|estimate - target| <= 4 std + ``slack`` everywhere (4 std: the Monte Carlo error of a few
    weights, two-sided; 0.005: the bias of the N_max = 3 pass against observations of 4 bounces)."""
    estimate, target, std = (np.asarray(x, float) for x in (estimate, target, std))
    bad = np.abs(estimate - target) > 4 * std + slack
    assert not bad.any(), f"{what}: error {np.round(estimate - target, 4).tolist()}, std {np.round(std, 4).tolist()}"


def test_unknown_sun_scale(photographed):
    """The sun 15 % brighter than declared, its scale unknown, the sky known: ρ and the scale
    within 4 std + 0.005 of the truth. In this tiny scene (2 segments, a small shadow) the sun's
    scale and ρ are told apart only by the shadowed ground, weakly, and the std says so:
    measured over seeds 0-3 at 16 spp, s_R = 1.39, 2.68, 1.49, 0.92 with std 0.54, 1.41, 0.57,
    0.35 (G and B std 0.14-0.22), max |z| of the 9 estimates 2.1; at 64 spp std 0.04-0.11,
    max |z| 1.9. With the scale taken as declared the same photographs put the sun's 15 % into ρ
    with a std that does not cover it (the control: asserted beyond 10 std)."""
    problem, _, ref = photographed
    wrong = run_symbolic(problem)
    assert (np.abs(wrong.estimate - ref) > 10 * wrong.std + 0.005).any()
    result = run_symbolic(_declared(problem, sun_unknown=True, sky_unknown=False))
    _within(result.estimate, ref, result.std, "rho")
    (entry,) = result.extras["illumination"]
    assert (entry["emitter"], entry["part"]) == (1, None)
    _within(entry["estimate"], [SUN] * 3, entry["std"], "sun scale")
    assert result.extras["field"]["unknown_scales"] == 1


def test_sun_and_sky_unknown_with_a_calibration_panel(photographed):
    """Both scales unknown (sun x 1.15, sky x 0.85) and the ground known (a calibration panel):
    the block's ρ and both scales within 4 std + 0.005, and now well determined: measured over
    seeds 0-3 at 16 spp, sun 1.144-1.166 (std 0.009-0.010), sky 0.844-0.852 (std 0.001-0.003),
    block error <= 0.013, max |z| 2.2."""
    problem, both, ref = photographed
    declared = _declared(dataclasses.replace(problem, observed=both), sun_unknown=True, sky_unknown=True,
                         known_ground=True)
    result = run_symbolic(declared)
    _within(result.estimate[1], ref[1], result.std[1], "block rho")
    sky, sun = result.extras["illumination"]
    assert (sky["emitter"], sun["emitter"]) == (0, 1)
    _within(sun["estimate"], [SUN] * 3, sun["std"], "sun scale")
    _within(sky["estimate"], [SKY] * 3, sky["std"], "sky scale")
    assert max(sun["std"]) < 0.02 and max(sky["std"]) < 0.005


def test_gauge_is_refused(photographed):
    """Every emitter unknown, no known segment: refused with one line naming both remedies; one
    known segment, or one emitter of known scale, lifts it."""
    problem, _, _ = photographed
    free = _declared(problem, sun_unknown=True, sky_unknown=True)
    with pytest.raises(ConfigError, match="scale as a number.*known: {kernel: value}"):
        SymbolicMethod(method_config("symbolic")).check_problem(free)
    check_gauge(_declared(problem, sun_unknown=True, sky_unknown=True, known_ground=True).scene)
    check_gauge(_declared(problem, sun_unknown=True, sky_unknown=False).scene)


DARK_BESIDE_UNKNOWN = [
    ("sunsky sun_scale 0", [Emitter("envmap", image=np.ones((4, 8, 3)), scale_unknown=True, source=0, part="sky"),
                            Emitter("directional", direction=np.array([0, 0, -1.0]), irradiance=np.zeros(3),
                                    source=0, part="sun")], "emitter 0/sun gives no light"),
    ("directional of irradiance 0", [Emitter("constant", radiance=np.ones(3), scale_unknown=True, source=0),
                                     Emitter("directional", direction=np.array([0, 0, -1.0]), irradiance=np.zeros(3),
                                             source=1)], "emitter 1 gives no light"),
    ("envmap of scale 0", [Emitter("constant", radiance=np.ones(3), scale_unknown=True, source=0),
                           Emitter("envmap", image=np.ones((4, 8, 3)), scale=0.0, source=1)], "emitter 1 gives no light"),
]


@pytest.mark.parametrize("emitters, dark", [c[1:] for c in DARK_BESIDE_UNKNOWN], ids=[c[0] for c in DARK_BESIDE_UNKNOWN])
def test_gauge_errors_dark_emitter(emitters, dark):
    """An emitter of known scale that gives no light beside one of unknown scale: refused as the
    gauge case it is (was: run, the unknown scale came back 1.9, 4.0 or 0.53 whatever the truth)."""
    scene = SimpleNamespace(emitters=emitters, segments=[], root=None)
    with pytest.raises(ConfigError, match=rf"^scene.yaml: every emitter's scale is unknown \({dark}, so its known "
                       r"scale fixes nothing\) and no segment is known"):
        check_gauge(scene)
    lit = dataclasses.replace(emitters[1], irradiance=np.ones(3), scale=1.0)
    check_gauge(SimpleNamespace(emitters=[emitters[0], lit], segments=[], root=None))     # a lit one fixes it


def test_per_segment_is_refused(photographed):
    problem, _, _ = photographed
    with pytest.raises(ConfigError, match="method.cost=per_segment cannot estimate"):
        SymbolicMethod(method_config("symbolic", cost="per_segment")).check_problem(
            _declared(problem, sun_unknown=True, sky_unknown=False))


def test_parameters_and_report_by_hand():
    """Two unknown scales after D = 5 weights: parameters 5 and 6, the start s = 1, and the report
    ``s = SCALE_MAX · h`` per channel (NaN: not observable, None)."""
    light = Illumination(((0, 0, "sky"), (1, 0, "sun")), first=5)
    assert [(p.index, p.segment_name, p.kernel) for p in light.parameters()] == [
        (5, "illumination:0/sky", "scale"), (6, "illumination:0/sun", "scale")]
    np.testing.assert_allclose(light.start(3) * SCALE_MAX, 1.0)
    est = np.full((7, 2), 0.25)
    est[6, 1] = np.nan
    rep = light.report(est, np.full((7, 2), 0.01))
    assert rep[0] == {"emitter": 0, "part": "sky", "estimate": [1.0, 1.0], "std": [0.04, 0.04]}
    assert rep[1]["estimate"] == [1.0, None]


def _glow() -> np.ndarray:
    """An 8 x 16 envmap brightest at the zenith (image top = +z), fading to 0 at the horizon."""
    rows = np.clip(np.cos(np.pi * (np.arange(8) + 0.5) / 8), 0, None)
    return np.broadcast_to((0.6 * rows)[:, None, None] * np.array([0.8, 0.9, 1.0]), (8, 16, 3)).astype(np.float32)


def test_a_second_environment_of_unknown_scale(photographed):
    """Two environments, the constant sky (known) and a zenith glow (an envmap, scale unknown),
    photographed with the glow 1.3 times brighter than declared: Mitsuba renders their sum, the
    pass splits it by the parts' radiance (the integrator's environment parts). The glow's scale
    and ρ within 4 std + 0.005 of the truth; measured over seeds 0-3 at 16 spp: glow R/G/B
    1.16-1.35 (std 0.015-0.071, weakest in red where the glow is dimmest), ρ errors <= 0.016,
    max |z| of the 9 estimates 1.5-2.0."""
    from framework.observe import render_references
    from framework.scene import Emitter
    problem, _, ref = photographed
    scene = problem.scene
    glow = Emitter("envmap", image=_glow(), scale=1.0, source=2)
    truth = dataclasses.replace(scene, emitters=[*scene.emitters, dataclasses.replace(glow, scale=1.3)])
    cams = problem.cameras
    observed = render_references(truth, cams, spp=256, max_depth=4, seed=1)
    declared = dataclasses.replace(scene, emitters=[*scene.emitters, dataclasses.replace(glow, scale_unknown=True)])
    result = run_symbolic(dataclasses.replace(problem, scene=declared,
                                              observed={c.name: o for c, o in zip(cams, observed)}))
    _within(result.estimate, ref, result.std, "rho")
    (entry,) = result.extras["illumination"]
    assert (entry["emitter"], entry["part"]) == (2, None)
    _within(entry["estimate"], [1.3] * 3, entry["std"], "glow scale")
