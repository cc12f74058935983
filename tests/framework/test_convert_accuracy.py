"""A converted OBJ and a converted CityJSON of ``city_block`` give the estimates of its hand-built
scene folder, within the Monte Carlo tolerance.

The street is built small (48 x 36 pixels, photographs at 64 spp); the survey's CityJSON
(earcut on walls with window holes and a door notch, survey coordinates with ``transform``) and
OBJ (the hand-built quads as 4-vertex faces, in survey coordinates) are converted with the same
photographs and the COLMAP model in survey coordinates. Each folder is inverted by the symbolic
method (8 spp, N_max = 2, seed 0), the hand-built one also at seeds 1-3.

Tolerance: the Monte Carlo spread of the hand-built estimates over the four seeds (sample
standard deviation σ per parameter and channel); a conversion's estimate must lie within
4 σ + 0.005 of their mean (σ from four seeds is itself uncertain, hence the 4 and the floor;
measured: the largest difference is 0.023 on the road, where σ = 0.015). Parameters the
single views cannot split (the windows' diffuse and specular weights: the hand-built run's own
std is 0.2-1.7 there, the paper's single-view remark) are left out of the comparison; the unobservable
ones (the buildings' GroundSurface) must be unobservable in all three.
"""
from __future__ import annotations

import numpy as np
import pytest

from factory import make_problem, run_symbolic
from framework.convert import convert
from scenes import city_block

SEEDS = (0, 1, 2, 3)


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("city")
    hand = city_block.build(root / "hand", width=48, height=36, spp=64)
    survey = hand / "survey"
    out = {"hand": hand}
    for name, source in (("cityjson", survey / "street.city.json"), ("obj", survey / "street.obj")):
        out[name] = convert(source, root / name, sparse=survey / "sparse", emitters=survey / "emitters.yaml",
                            images=hand / "images", kernels={"*/Window": ("diffuse", "specular")}).folder
    return out


def _estimate(folder, seed: int):
    from framework.results import results_dict

    problem = make_problem(folder, None, f"seed={seed}")
    result = run_symbolic(problem)
    names = [(p.segment_name, p.kernel) for p in problem.parameters]
    origin = results_dict(problem, result, method="symbolic", settings={}, views=[], relit=[])["origin"]
    assert origin == list(city_block.ORIGIN)            # results.json says which origin
    return names, np.asarray(result.estimate, float), np.asarray(result.std, float)


@pytest.mark.slow
def test_converted_match_hand_built(folders):
    runs = [_estimate(folders["hand"], s) for s in SEEDS]
    names = runs[0][0]
    hand = np.array([r[1] for r in runs])
    mean, sigma = hand.mean(axis=0), hand.std(axis=0, ddof=1)
    split = np.array([s.endswith("/Window") for s, _ in names])     # the windows' ill-determined split
    seen = np.isfinite(mean).all(axis=1)
    assert [n for n, s in zip(names, seen) if not s] == [(f"b{i}/GroundSurface", "diffuse") for i in (1, 2, 3)]
    assert sum(seen & ~split) == 10
    for kind in ("cityjson", "obj"):
        got_names, est, _ = _estimate(folders[kind], 0)
        assert got_names == names
        assert np.array_equal(np.isfinite(est).all(axis=1), seen)
        keep = seen & ~split
        diff = np.abs(est[keep] - mean[keep])
        bound = 4 * sigma[keep] + 0.005
        worst = np.unravel_index(np.argmax(diff - bound), diff.shape)
        assert (diff <= bound).all(), (kind, np.array(names, dtype=object)[keep][worst[0]], diff[worst], bound[worst])
