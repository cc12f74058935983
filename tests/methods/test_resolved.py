"""Every ``auto`` of the symbolic options decided in one place (:mod:`methods.symbolic.loop.resolved`),
with the reason results.json records; the rules by hand from the module's table."""
from __future__ import annotations

import dataclasses

import pytest

from factory import method_config
from framework.options import build
from methods.symbolic.loop.resolved import Facts, field_reasons, resolved
from methods.symbolic.options import SymbolicOptions

#: a rendered scene of 3 views at 64 spp: no photographs, nothing marked, no lens, known light
RENDERED = Facts(photographs=False, weights=False, per_view=False, quantised=False, distorted=False,
                 vignetting="none", scales=0, spp=64, views=3)
#: photographs with masks (pixel weights): the field path
PHOTOGRAPHS = dataclasses.replace(RENDERED, photographs=True, weights=True)


def _options(**overrides) -> SymbolicOptions:
    return build(SymbolicOptions, {**method_config("symbolic"), **overrides})


@pytest.mark.parametrize("facts, overrides, bias, std", [
    (PHOTOGRAPHS, {}, "richardson", "cluster"),                            # photographs: both on
    (RENDERED, {}, "none", "sandwich"),                                    # rendered radiance: as solved
    (dataclasses.replace(PHOTOGRAPHS, spp=30), {}, "none", "cluster"),     # no four equal quarters
    (PHOTOGRAPHS, {"gram": "plain"}, "none", "cluster"),                   # no halves to pair
    (PHOTOGRAPHS, {"cost": "per_segment"}, "richardson", "sandwich"),      # the cluster std is the joint cost's
    (PHOTOGRAPHS, {"bias": "none", "std": "sandwich"}, "none", "sandwich"),   # explicit values stay
    (RENDERED, {"bias": "richardson", "std": "cluster"}, "richardson", "cluster"),
])
def test_bias_and_std(facts, overrides, bias, std):
    out = resolved(_options(**overrides), facts)
    assert (out.options.bias, out.options.std) == (bias, std)
    assert ("bias" in out.why) == ("bias" not in overrides)


@pytest.mark.parametrize("facts, overrides, align", [
    (PHOTOGRAPHS, {}, "rotation"),                  # photographs: their poses are a survey's
    (RENDERED, {}, "none"),                         # rendered scenes: exact poses
    (PHOTOGRAPHS, {"refine": 0}, "none"),           # no pass to register before
    (PHOTOGRAPHS, {"align": "shift"}, "shift"),     # explicit values stay
    (RENDERED, {"align": "rotation"}, "rotation"),
])
def test_align(facts, overrides, align):
    assert resolved(_options(**overrides), facts).options.align == align


def test_linear_photographs_are_aligned_with_the_cluster_std_but_not_corrected():
    """Photographs decoded as linear radiance (EXR) with no pixel weights, gains or robust rounds:
    aligned and cluster std as any photographs, but no bias correction (their L2 solve is as near
    linear as a rendered scene's); a rendered scene keeps exact poses and the pixel sandwich."""
    linear = dataclasses.replace(RENDERED, photographs=True)
    out = resolved(_options(), linear).options
    assert (out.bias, out.std, out.align, out.robust) == ("none", "cluster", "rotation", "none")
    out = resolved(_options(), RENDERED).options
    assert (out.bias, out.std, out.align, out.robust) == ("none", "sandwich", "none", "none")


@pytest.mark.parametrize("change, boundary, robust", [
    ({}, 0, "none"),
    ({"distorted": True}, 1, "cauchy"),        # the boundary's pixels are pixel weights
    ({"weights": True}, 0, "cauchy"),
    ({"per_view": True}, 0, "cauchy"),
    ({"quantised": True}, 0, "cauchy"),
    ({"vignetting": "estimate"}, 0, "none"),   # a lens alone is no reason to reweigh
])
def test_boundary_and_robust(change, boundary, robust):
    facts = dataclasses.replace(RENDERED, **change)
    out = resolved(_options(), facts)
    assert (out.options.boundary, out.options.robust) == (boundary, robust)
    assert out.why["robust"]["value"] == robust and out.why["boundary"]["value"] == boundary
    assert bool(field_reasons(facts, boundary=boundary, robust=robust)) == (robust != "none" or "vignetting" in change)


def test_consistency_only_with_robust_rounds_and_views_to_compare():
    three = resolved(_options(consistency="auto"), dataclasses.replace(PHOTOGRAPHS, views=3))
    assert three.options.consistency == "auto" and "disagreement" in three.why["consistency"]["why"]
    two = resolved(_options(consistency="auto"), dataclasses.replace(PHOTOGRAPHS, views=2))
    assert two.options.consistency == "none"
    assert resolved(_options(consistency="auto", robust="none"), PHOTOGRAPHS).options.consistency == "none"
    assert "consistency" not in resolved(_options(), PHOTOGRAPHS).why      # the default none: not auto


def test_why_names_every_auto_option_and_no_other():
    out = resolved(_options(), PHOTOGRAPHS)
    assert set(out.why) == {"boundary", "robust", "std", "std_device", "align", "bias", "solver.starts"}
    assert out.why["std"] == {"value": "cluster", "why": out.why["std"]["why"]} and "photographs" in out.why["std"]["why"]
    assert out.why["solver.starts"]["value"] == "auto"          # decided per parameter block by the solve
    fixed = resolved(_options(boundary=0, robust="none", std="sandwich", std_device="host", align="none",
                              bias="none", solver={**method_config("symbolic")["solver"], "starts": 2}), PHOTOGRAPHS)
    assert fixed.why == {} and fixed.options == _options(boundary=0, robust="none", std="sandwich", std_device="host",
                                                         align="none", bias="none",
                                                         solver={**method_config("symbolic")["solver"], "starts": 2})


def test_a_run_records_its_decisions(tmp_path):
    """results.json ``options_resolved`` of a run on the tiny rendered scene: sandwich, its
    products on the host (the tests' llvm_ad_rgb), no alignment, no correction, each with its reason."""
    from factory import make_problem, make_tiny_scene, run_symbolic
    root = make_tiny_scene(tmp_path / "s", size=8)
    out = run_symbolic(make_problem(root, None, "render.spp=8"), refine=0).extras["options_resolved"]
    assert {k: v["value"] for k, v in out.items()} == {"boundary": 0, "robust": "none", "std": "sandwich",
                                                      "std_device": "host", "align": "none", "bias": "none",
                                                      "solver.starts": "auto"}
    assert "rendered by the run" in out["std"]["why"]


@pytest.mark.parametrize("backend, given, value", [
    ("cuda", "auto", "device"), ("llvm", "auto", "host"),          # the GPU's kernels, the CPU's scipy
    ("cuda", "host", "host"), ("llvm", "device", "device"),        # explicit values stay
])
def test_std_device(backend, given, value):
    out = resolved(_options(std_device=given), dataclasses.replace(RENDERED, backend=backend))
    assert out.options.std_device == value
    assert ("std_device" in out.why) == (given == "auto")
