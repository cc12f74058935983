"""How well the model explains each material (:mod:`methods.symbolic.fit.fit_quality`): a material an
unmodelled object covers in every view is flagged with the reason; a clean one is not.

The tiny scene, 4 views at 16 spp, photographs' field path (pixel weights 1: robust Cauchy);
the "van" darkens (x 0.3) the first 60 % of the ground's rows in every view, so that no view
disagrees with another (the views' consistency cannot see it). Measured at seed 0: clean
ground chi2 0.85, dropped 2.6 %, block 0.66 / 3.2 %; with the van the ground's robust weights
left out 49 % of its pixels (its ρ_d off by -0.065..-0.107), the block 6.3 %. The thresholds
(DROP_MAX 10 %, CHI2_MAX 4) sit far from both; the kept pixels' steps (``pull``): clean ground
0.4 std, block 0.4 std; with the van the ground's 0.043 (9.8 std, 0.4 of its error: the van's
pixels the fit keeps bias them too), the block's 1.1 std.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from factory import run_symbolic, tiny_problem
from methods.symbolic.fit.fit_quality import (CHI2_MAX, DROP_MAX, PULL_FLOOR, PULL_MAX, PULL_NOISE, _Pulls, _verdict,
                                              floored_std, poor_parameters)


@pytest.fixture(scope="module")
def courtyard(tmp_path_factory):
    """``(clean problem, problem with the van in every view)``, both on the field path."""
    from framework.render.mitsuba_scene import segment_maps
    problem = tiny_problem(tmp_path_factory.mktemp("fq") / "s", n_views=4, spp=16)
    problem = dataclasses.replace(problem, weights={c.name: np.ones((c.height, c.width)) for c in problem.cameras})
    observed = {}
    for cam in problem.cameras:
        ground = np.flatnonzero(segment_maps(problem.scene, [cam])[cam.name].ravel() == 0)
        rows = np.sort(np.unique(ground // cam.width))
        covered = ground[np.isin(ground // cam.width, rows[: int(0.6 * len(rows))])]
        img = problem.observed[cam.name].reshape(-1, 3).copy()
        img[covered] *= 0.3
        observed[cam.name] = img.reshape(problem.observed[cam.name].shape)
    return problem, dataclasses.replace(problem, observed=observed)


def test_an_object_in_every_view_flags_its_material(courtyard):
    clean, van = courtyard
    quiet = run_symbolic(clean, bias="none", refine=0)
    q = quiet.extras["fit_quality"]
    assert set(q) == {"ground", "block"}
    assert not any(m["poor"] for m in q.values()) and not any(quiet.extras["ill_determined"])
    assert all(m["dropped"] < 0.05 and m["chi2"] < 2.0 for m in q.values())
    assert all(abs(z) < 1 for m in q.values() for z in m["pull_std"]["diffuse"])
    assert set(q["ground"]["views"]) == {c.name for c in clean.cameras}
    out = run_symbolic(van, bias="none", refine=0)
    q = out.extras["fit_quality"]
    assert q["ground"]["poor"] and not q["block"]["poor"]
    assert q["ground"]["dropped"] > DROP_MAX and "robust weights left out" in q["ground"]["why"]
    # rendered observations keep the pixel sandwich std (no images/): the block moves 2.35 of its
    # smaller std (0.017 absolute, seed-fixed), inside the verdict's PULL_MAX std + PULL_FLOOR
    assert q["ground"]["pull_std"]["diffuse"][0] > 5 and abs(q["block"]["pull_std"]["diffuse"][0]) < PULL_MAX
    flagged = {p.segment_name for p, ill in zip(van.parameters, out.extras["ill_determined"]) if ill}
    assert flagged == {"ground"}
    assert all(w is None or "left out" in w for w in out.extras["ill_determined_why"])


def test_verdicts_by_hand():
    """Over all views: a share dropped above DROP_MAX (10 %), else a chi2 above CHI2_MAX, is poor."""
    assert DROP_MAX == 0.10
    views = {"a": {"pixels": 10, "dropped": 0.3, "chi2": 1.0}, "b": {"pixels": 10, "dropped": 0.04, "chi2": 1.0}}
    assert _verdict({"pixels": 20, "dropped": 0.17, "chi2": 1.0}, views)["poor"]
    assert "up to 30 % in a" in _verdict({"pixels": 20, "dropped": 0.17, "chi2": 1.0}, views)["why"]
    assert _verdict({"pixels": 20, "dropped": 0.08, "chi2": CHI2_MAX + 0.1}, views)["poor"]
    assert "Birge" in _verdict({"pixels": 20, "dropped": 0.08, "chi2": 9.0}, views)["why"]
    assert not _verdict({"pixels": 20, "dropped": 0.08, "chi2": 1.0}, views)["poor"]

    @dataclasses.dataclass
    class P:
        segment_name: str
    flags, why = poor_parameters({"wall": {"poor": True, "why": "w"}, "road": {"poor": False, "why": None}},
                                 [P("wall"), P("road"), P("sky")])
    assert flags.tolist() == [True, False, False] and why == ["w", None, None]


def _pulls(x, std, H, grad):
    """A :class:`_Pulls` of one material (segment 0) with weights ``diffuse`` and ``specular`` at
    ``x`` ((2, C)), their ``std`` and its kept pixels' summed cross Gram ``H`` ((C, 2, 2)) and
    gradient ``grad`` ((C, 2)), as :meth:`_Pulls.add` leaves them."""
    pulls = _Pulls.__new__(_Pulls)
    pulls.x, pulls.std = np.asarray(x, float), np.asarray(std, float)
    pulls.segment, pulls.kernels = np.array([0, 0]), ["diffuse", "specular"]
    pulls.sums = {0: [np.asarray(H, float), np.asarray(grad, float)]}
    return pulls


def test_pull_by_hand():
    """The step -H⁻¹g per channel: H = diag(4, 1) and g = (-0.08, 0.01) give (0.02, -0.01); at std
    0.004 the diffuse step is 5 std, beyond PULL_MAX std + PULL_FLOOR (0.017), the specular 2.5
    std is not (0.01 <= 0.017); at std 0.005 neither is (0.02 <= 0.02). A specular weight that the step would take below 0 is held on that
    bound and the diffuse step solved again (H = [[4, 2], [2, 2]], g = (-0.08, 0.06): free step
    (0.07, -0.1); from specular 0: (0.02, 0); from specular 0.04: d_s = -0.04, d_d = (0.08 -
    2 x -0.04) / 4 = 0.04); a weight without a finite positive std (known, unobservable) is not
    stepped and the others are solved without it."""
    assert (PULL_MAX, PULL_FLOOR) == (3.0, 0.005)
    H = [[[4.0, 0.0], [0.0, 1.0]]]
    pull, worst = _pulls([[0.3], [0.1]], [[0.004], [0.004]], H, [[-0.08, 0.01]]).of(0)
    assert pull["pull"]["diffuse"] == pytest.approx([0.02]) and pull["pull"]["specular"] == pytest.approx([-0.01])
    assert pull["pull_std"]["diffuse"] == pytest.approx([5.0]) and pull["pull_std"]["specular"] == pytest.approx([-2.5])
    assert worst == ("diffuse", 0, pytest.approx(0.02), pytest.approx(5.0))
    _, none = _pulls([[0.3], [0.1]], [[0.005], [0.005]], H, [[-0.08, 0.01]]).of(0)
    assert none is None                                   # 0.02 <= 3 x 0.005 + 0.005
    coupled = [[[4.0, 2.0], [2.0, 2.0]]]
    free, _ = _pulls([[0.3], [0.1]], [[0.01], [0.01]], coupled, [[-0.08, 0.06]]).of(0)
    assert free["pull"]["diffuse"] == pytest.approx([0.07]) and free["pull"]["specular"] == pytest.approx([-0.1])
    held, _ = _pulls([[0.3], [0.0]], [[0.01], [0.01]], coupled, [[-0.08, 0.06]]).of(0)
    assert held["pull"]["diffuse"] == pytest.approx([0.02]) and held["pull"]["specular"] == pytest.approx([0.0])
    near, _ = _pulls([[0.3], [0.04]], [[0.01], [0.01]], coupled, [[-0.08, 0.06]]).of(0)
    assert near["pull"]["diffuse"] == pytest.approx([0.04]) and near["pull"]["specular"] == pytest.approx([-0.04])
    fixed, _ = _pulls([[0.3], [0.1]], [[0.01], [np.nan]], coupled, [[-0.08, 0.06]]).of(0)
    assert fixed["pull"]["diffuse"] == pytest.approx([0.02]) and fixed["pull"]["specular"] == [None]


def test_pull_verdict():
    """A step beyond PULL_MAX std + PULL_FLOOR makes the material poor with the weight, channel,
    step and its size in std in the reason; the drop and chi2 criteria come first."""
    views = {"a": {"pixels": 10, "dropped": 0.05, "chi2": 1.0}}
    v = _verdict({"pixels": 10, "dropped": 0.02, "chi2": 0.62}, views, ("diffuse", 2, 0.040, 3.6))
    assert v["poor"] and "diffuse weight by +0.040 in B (3.6 std)" in v["why"] and "2 % of its own" in v["why"]
    assert not _verdict({"pixels": 10, "dropped": 0.02, "chi2": 0.62}, views, None)["poor"]
    assert "robust weights left out 19 %" in _verdict({"pixels": 10, "dropped": 0.19, "chi2": 0.96}, views,
                                                       ("diffuse", 0, 0.1, 9.0))["why"]


def test_floored_std_by_hand():
    """A weight's std is raised to |pull| / PULL_NOISE (1.5) where that is larger: the wall's ρ_d
    pull 0.003, -0.0006 and none (null) at std 0.001, 0.001, 0.002 gives std 0.002 (x2), 0.001
    (0.0004 < 0.001: kept), 0.002 (no pull: kept); a material without a pull (the sky) and a weight
    with a NaN std keep theirs."""
    P = lambda seg, kernel: type("P", (), {"segment_name": seg, "kernel": kernel})()
    params = [P("wall", "diffuse"), P("wall", "specular"), P("sky", "diffuse")]
    quality = {"wall": {"pull": {"diffuse": [0.003, -0.0006, None], "specular": [0.01, 0.0, 0.0]}},
               "sky": {"pixels": 3}}
    std = np.array([[0.001, 0.001, 0.002], [np.nan, 0.004, 0.004], [0.1, 0.1, 0.1]])
    out, scale = floored_std(quality, params, std)
    assert PULL_NOISE == 1.5
    np.testing.assert_allclose(out[0], [0.002, 0.001, 0.002])
    assert np.isnan(out[1, 0]) and np.allclose(out[1, 1:], 0.004) and np.allclose(out[2], 0.1)
    np.testing.assert_allclose(scale["wall"]["diffuse"], [2.0, 1.0, 1.0])
    assert scale["wall"]["specular"] == [1.0, 1.0, 1.0] and "sky" not in scale
    assert np.isnan(std[1, 0]) and std[0, 0] == 0.001              # the input is not modified


#: issue 44's target: a weight further than this from the truth is wrong (diffuse, specular)
TOLERANCE = {"diffuse": 0.03, "specular": 0.05}


@pytest.mark.slow
def test_a_car_in_every_view_is_no_confident_wrong_number(tmp_path):
    """The bundled ``urban_canyon_car`` (100 px, seed 0: a red car over 18-27 % of the asphalt in
    every street view, unmasked), its segments without a specular weight in the truth (roof,
    balcony, asphalt, awning) fitted with the diffuse kernel only (8 weights instead of 12: the
    solve three times cheaper, the car as it was), the defaults but one refinement pass and no
    bias correction. The target: the car-covered material (asphalt) flagged or within 0.03 / 0.05
    of the truth, and no weight left unflagged beyond 3 std + 0.005.

    Measured at 9f23d5a: the asphalt's ρ_d G, B 0.0143 and 0.0155 low at std 0.0025 (5.8 std),
    19.6 % of its pixels left out (DROP_MAX 10 %): flagged; the windows 13.7 % left out (ρ_d R
    0.043 high, 4.7 std): flagged; of the unflagged weights the worst |error| is 0.39 of its
    3 std + 0.005 (the wall's ρ_d B). Under the former 25 % threshold nothing was flagged."""
    import json
    import os
    import shutil
    import subprocess
    import sys

    import yaml
    from scenes import BUNDLED_DIR

    folder = tmp_path / "urban_canyon_car"
    shutil.copytree(BUNDLED_DIR / "urban_canyon_car", folder, ignore=shutil.ignore_patterns("preview.png"))
    scene = yaml.safe_load((folder / "scene.yaml").read_text())
    for seg in scene["segments"]:
        if seg["reference"].get("specular", 0.0) == 0.0:
            seg["kernels"], seg["reference"] = ["diffuse"], {"diffuse": seg["reference"]["diffuse"]}
    (folder / "scene.yaml").write_text(yaml.safe_dump(scene, sort_keys=False))
    args = [f"scene.dir={folder}", "views=all", "method=symbolic", "method.refine=1", "method.bias=none",
            "report=false", f"hydra.run.dir={tmp_path / 'run'}", f"cache.dir={tmp_path / 'cache'}"]
    proc = subprocess.run([sys.executable, "-m", "framework.run", *args], capture_output=True, text=True,
                          timeout=880, env=dict(os.environ, HYDRA_FULL_ERROR="0"))
    assert proc.returncode == 0, proc.stderr[-2000:]
    res = json.loads((tmp_path / "run" / "results.json").read_text())
    quality = res["fit_quality"]
    assert quality["asphalt"]["dropped"] > DROP_MAX and quality["asphalt"]["poor"]
    rows = {(p["segment"], p["kernel"]): p for p in res["parameters"]}
    asphalt = rows[("asphalt", "diffuse")]
    assert asphalt["ill_determined"] and "left out" in asphalt["why"] or \
        max(map(abs, asphalt["error"])) <= TOLERANCE["diffuse"]
    for (segment, kernel), p in rows.items():
        if p.get("ill_determined") or not p.get("observable", True):
            continue
        for error, std in zip(p["error"], p["std"]):
            assert abs(error) <= 3 * std + 0.005, (segment, kernel, error, std)


def test_dense_and_sparse_jacobian_give_the_same_quality(courtyard, monkeypatch):
    """The pulls and chi² of every material alike (1e-9 relative) whether the coefficients
    multiply the Jacobian dense (few parameters, the default here) or sparse."""
    from methods.symbolic.system import pixel_matrices
    clean, _ = courtyard
    out = []
    for bound in (pixel_matrices.DENSE_JACOBIAN_COLUMNS, 0):
        monkeypatch.setattr(pixel_matrices, "DENSE_JACOBIAN_COLUMNS", bound)
        out.append(run_symbolic(clean, bias="none", refine=0).extras["fit_quality"])
    for name, m in out[0].items():
        for key in ("chi2", "dropped"):
            assert m[key] == pytest.approx(out[1][name][key], rel=1e-9)
        for kernel, pulls in m["pull_std"].items():
            np.testing.assert_allclose(pulls, out[1][name]["pull_std"][kernel], rtol=1e-9)
