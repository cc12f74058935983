"""The benchmark section "misfit" (:mod:`bench.misfit`): its row summary by hand, its markdown,
and its whole code path at ``--quick`` size."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from bench import misfit
from bench.sizes import QUICK

GAINS = {"street_002.jpg": np.array([1.0, 1.0, 1.0]), "street_000.jpg": np.array([1.5, 1.6, 1.7])}
SHIFTS = {"street_000.jpg": np.array([0.2, 0.5]), "street_002.jpg": np.array([-0.3, 0.0])}


def _results(*, wall_err=0.02, wall_std=0.01, window_std=0.02):
    """Two determined weights (wall diffuse, window specular), one ill-determined, one
    unobservable; the reference view's gains 1 and another view's 2 % high in red; one aligned
    view."""
    return {"parameters": [
        {"segment": "wall", "kernel": "diffuse", "error": [wall_err, -0.01, 0.0], "std": [wall_std] * 3,
         "observable": True, "ill_determined": False},
        {"segment": "window", "kernel": "specular", "error": [0.04] * 3, "std": [window_std] * 3,
         "observable": True, "ill_determined": False},
        {"segment": "roof", "kernel": "specular", "error": [0.3] * 3, "std": [0.2] * 3,
         "observable": True, "ill_determined": True},
        {"segment": "asphalt", "kernel": "diffuse", "error": [0.5] * 3, "std": None, "observable": False}],
        "exposure": [{"view": "street_002.jpg", "estimate": [1.0, 1.0, 1.0], "std": None, "reference": True},
                     {"view": "street_000.jpg", "estimate": [1.53, 1.6, 1.7 * 0.99], "std": [0.01] * 3,
                      "reference": False}],
        "alignment": [{"view": "street_000.jpg", "shift_px": [0.5, 0.1], "accepted": True}], "renders": 3}


def test_summary_by_hand():
    """Wall diffuse errors 0.02, -0.01, 0 at std 0.01 (z 2, -1, 0) and window specular 0.04 x 3
    at std 0.02 (z 2, 2, 2): RMS z = sqrt((4 + 1 + 0 + 4 + 4 + 4) / 6) = sqrt(17 / 6) = 1.68,
    above 1.5, so the targets are not met although every error is within 3 std + 0.005 (0.035 and
    0.065) and the worst diffuse 0.02, specular 0.04 and gain 1.53 / 1.5 - 1 = 2 % meet theirs.
    The ill-determined roof and the unobservable asphalt count nowhere. Pose: |(0.5, 0.1) - (0.2,
    0.5)| = |(0.3, -0.4)| = 0.5 px. With the stds doubled (z 1, -0.5, 0, 1, 1, 1: RMS
    sqrt(4.25 / 6) = 0.84) every target is met; a wall error of 0.05 at std 0.01 is beyond
    (0.05 > 0.035)."""
    s = misfit.summarise(_results(), GAINS, SHIFTS)
    assert s["worst_diffuse"] == pytest.approx(0.02) and s["worst_specular"] == pytest.approx(0.04)
    assert s["ill_determined"] == 1 and s["n_z"] == 6 and s["beyond"] == 0
    assert s["rms_z"] == pytest.approx(math.sqrt(17 / 6))
    assert s["gain_error"] == pytest.approx(0.02) and s["pose_error"] == pytest.approx(0.5)
    assert s["met"] is False
    ok = misfit.summarise(_results(wall_std=0.02, window_std=0.04), GAINS, SHIFTS)
    assert ok["rms_z"] == pytest.approx(math.sqrt(4.25 / 6)) and ok["met"] is True
    bad = misfit.summarise(_results(wall_err=0.05, wall_std=0.02, window_std=0.04), GAINS, SHIFTS)
    assert bad["beyond"] == 0 and bad["worst_diffuse"] == pytest.approx(0.05) and bad["met"] is False
    beyond = misfit.summarise(_results(wall_err=0.05), GAINS, SHIFTS)
    assert beyond["beyond"] == 1
    assert misfit.summarise({**_results(), "alignment": None}, GAINS, SHIFTS)["pose_error"] is None


def test_markdown_with_a_failure():
    rows = [{"row": "a", "label": misfit.ROWS["a"][0], "rc": 0, "wall_s": 12.0,
             **misfit.summarise(_results(wall_std=0.02, window_std=0.04), GAINS, SHIFTS)},
            {"row": "b", "label": misfit.ROWS["b"][0], "rc": 1, "wall_s": 3.0, "met": False,
             "refusal": "RuntimeError: boom"}]
    text = "\n".join(misfit.markdown(rows))
    assert "## 11. Misfit (urban_canyon_misfit, all views)" in text
    assert "| (a) defaults (cluster std, bias correction, alignment) | 0.0200 | 0.0400 | 2.00 | 0.84 | 0 / 6 | 1 | 0.50 | 12.0 | **met** |" in text
    assert "failed (exit 1): `RuntimeError: boom`" in text and "**not met**" in text
    assert misfit.markdown([]) == []


def test_car_row_by_hand():
    """Row (e)'s summary: its weights table lists every weight with an error (truth = the
    reference, z = error / std, the why of a flagged one or its std) and its target is issue 44's
    (worst diffuse, worst specular and the count beyond 3 std + 0.005 over the determined weights;
    gains and RMS z are not part of it): met with the gain 2 % off and RMS z 1.68; a wall error of
    0.05 at std 0.01 is beyond; the markdown holds the row and its table."""
    res = _results()
    res["parameters"][2]["why"] = "the pixels its robust weights left out pull it"
    for p in res["parameters"]:
        p["estimate"] = [0.5] * 3
        p["reference"] = [0.5 - e for e in p["error"]]
    table = misfit.weights_table(res)
    assert [(w["segment"], w["kernel"]) for w in table] == [("wall", "diffuse"), ("window", "specular"),
                                                              ("roof", "specular"), ("asphalt", "diffuse")]
    assert table[0]["truth"] == pytest.approx([0.48, 0.51, 0.5]) and table[0]["z"] == pytest.approx([2.0, -1.0, 0.0])
    assert table[2]["ill_determined"] and table[2]["why"].startswith("the pixels")
    assert not table[3]["observable"] and table[3]["z"] is None
    s = misfit.summarise(res, GAINS, SHIFTS)
    assert s["met"] is False and misfit.car_target_met(s) is True
    assert misfit.car_target_met(misfit.summarise(_results(wall_err=0.05), GAINS, SHIFTS)) is False
    row = {"row": "e", "label": misfit.CAR_ROWS["e"][0], "rc": 0, "wall_s": 5.0, **s, "weights": table,
           "met": misfit.car_target_met(s)}
    text = "\n".join(misfit.markdown([row]))
    assert misfit.CAR_ROWS["e"][0] in text and "| roof | specular |" in text and "the pixels its robust" in text
    assert "| asphalt | diffuse | 0.500 / 0.500 / 0.500 | 0.000 / 0.000 / 0.000 | n/a | n/a | not observable |" in text


def test_rows_and_targets_match_the_brief():
    assert list(misfit.CAR_ROWS) == ["e"] and misfit.CAR_ROWS["e"][1] == []
    assert list(misfit.ROWS) == ["a", "b", "c", "d"]
    assert misfit.ROWS["a"][1] == []
    assert misfit.ROWS["b"][1] == ["method.std=sandwich", "method.bias=none", "method.align=none"]
    assert misfit.ROWS["c"][1] == ["method.align=none"]
    assert (misfit.DIFFUSE_TOL, misfit.SPECULAR_TOL, misfit.GAIN_TOL, misfit.RMS_Z) == (0.03, 0.05, 0.03, (0.7, 1.5))
    assert "method.refine=0" not in QUICK.misfit_extra and QUICK.misfit_image == 40


def test_misfit_rows_errors():
    """A row key that is neither in ROWS nor in CAR_ROWS is refused before anything is built."""
    import dataclasses
    with pytest.raises(ValueError, match=r"misfit_rows \['z'\] unknown"):
        misfit.run(dataclasses.replace(QUICK, misfit_rows=("a", "z")), Path("/nonexistent"), log=lambda *a: None)


@pytest.mark.slow
def test_quick_section_runs(tmp_path):
    """``python -m bench --quick --sections misfit``'s code path: the rows ``QUICK.misfit_rows``
    keeps, the car row alone (the defaults on photographs, as row (a), on the misfit street with a
    car the model lacks), on the car scene built at 20 pixels, 4 spp, one refinement pass: it
    aligns (the default aligns photographs) and reports a pose error and gains; the misfit scene
    is not built, no row using it.

    What the section exists for that this size can show: no confident wrong number. Every weight
    is either determined and within 3 std + 0.005 of the truth, or flagged ill-determined (at 4 spp
    and 20 pixels most are flagged, and the gains are far from their truth: seeds 0-4, 2026-12-05:
    11 or 12 of 12 weights flagged, none beyond, gain errors 25-62 %)."""
    rows = misfit.run(QUICK, tmp_path, log=lambda *a: None)
    assert QUICK.misfit_rows == ("e",) and [r["row"] for r in rows] == ["e"]
    assert not (tmp_path / "scenes" / "urban_canyon_misfit_40").exists()
    for r in rows:
        assert r["rc"] == 0 and r["gain_error"] is not None and r["pose_error"] is not None
        assert r["beyond"] == 0 and r["ill_determined"] >= 1, r
    assert len(rows[-1]["weights"]) == 12 and rows[-1]["scene"] == "urban_canyon_car_20"
    text = "\n".join(misfit.markdown(rows))
    assert "## 11. Misfit" in text and text.count("| (") == len(QUICK.misfit_rows)
