import pytest
"""reports: per-run report and comparison content, from fake run folders."""
import json
import re
from pathlib import Path

import numpy as np
from fakes import REPORT_REFS, REPORT_SEEDS, make_fake_run, report_error_of

from reports import write_comparison, write_run_report
from reports.__main__ import main
from reports.data import fmt_num


def _referenced_files(text: str, pattern: str) -> list[str]:
    return re.findall(pattern, text)


def test_run_report_parameter_table(tmp_path):
    run = make_fake_run(tmp_path / "run", method="symbolic", seed=1)
    md_path, html_path = write_run_report(run)
    md = md_path.read_text()
    ref = REPORT_REFS[("wall", "diffuse")]
    cells = []
    for c in range(3):
        err = report_error_of("symbolic", 1, c)
        cells += [fmt_num(ref[c]), fmt_num(ref[c] + err), fmt_num(err), fmt_num(0.001)]
    assert "| wall | ρ_d | " + " | ".join(cells) + " |" in md
    assert "| wall | ρ_d | 0.7200 | 0.7400 | 0.0200 | 0.0010 | 0.7000 | 0.7400 | 0.0400 |" in md
    assert "|  | ρ_s | 0.0800 | 0.1000 | 0.0200 |" in md          # paper form: object once
    assert "| Object | Param. | R Ref. | R Estim. | R Error | R Std | G Ref." in md
    html = html_path.read_text()
    assert '<th colspan="4">R</th>' in html and "ρ<sub>d</sub>" in html


def test_run_report_sections_and_images_exist(tmp_path):
    run = make_fake_run(tmp_path / "run")
    md_path, html_path = write_run_report(run)
    md = md_path.read_text()
    for heading in ("## Overview", "## Parameters", "## Timings", "## Convergence", "## Views",
                    "### Image metrics", "## Parameter correlation", "## Relit images"):
        assert heading in md
    assert "| render (s) | 1.800 |" in md and "| total (s) | 2.000 |" in md
    assert "| renders | 1 |" in md
    assert "| v0.png | 0.05000 |" in md                 # RMSE of the constant offset
    srcs = _referenced_files(html_path.read_text(), r'<img src="([^"]+)"')
    assert len(srcs) == 7                              # convergence, 4 panels, correlation, relit
    for src in srcs:
        assert (run / src).stat().st_size > 100, src
    assert "http://" not in html_path.read_text() and "https://" not in html_path.read_text()


def test_mono_run_has_one_number_per_field(tmp_path):
    run = make_fake_run(tmp_path / "mono", channels=("Y",), correlation=False)
    md = write_run_report(run)[0].read_text()
    assert "| Object | Param. | Ref. | Estim. | Error | Std |" in md
    assert "| asphalt | ρ_d | 0.2000 | 0.2100 | 0.0100 | 0.0010 |" in md
    assert "## Parameter correlation" not in md


def test_unobservable_parameter_and_missing_image(tmp_path):
    run = make_fake_run(tmp_path / "run", correlation=False)
    res = json.loads((run / "results.json").read_text())
    res["parameters"][1].update(estimate=None, error=None, std=None, observable=False)
    res["views"][0]["reconstruction"] = "images/gone.exr"
    (run / "results.json").write_text(json.dumps(res))
    md = write_run_report(run)[0].read_text()
    assert "|  | ρ_s | no | 0.0800 | — | — | — |" in md
    assert "reconstruction: cannot read images/gone.exr" in md


def test_report_200px_single_view(tmp_path):
    """A street-view-sized run gets its report (its time is in results.json timings_s.report and
    the benchmark, not asserted here)."""
    run = make_fake_run(tmp_path / "big", size=200)
    md, html = write_run_report(run)
    assert md.is_file() and html.is_file()
    assert "report_files/" in md.read_text()


@pytest.mark.slow
def test_comparison_numbers(fake_sweep, capsys):
    assert main([str(fake_sweep)]) == 0
    md = (fake_sweep / "comparison.md").read_text()
    # symbolic wall rho_d R: errors 0.01, 0.02, 0.03 over seeds -> 0.0200 ± 0.0100
    assert "| wall | ρ_d | R | 0.7200 | 0.0200 ± 0.0100 | -0.0400 ± 0.0200 |" in md
    assert "|  | ρ_d | B | 0.6800 | 0.0600 ± 0.0300 | -0.1200 ± 0.0600 |" in md
    # total time: symbolic 2,3,4 -> 3 ± 1; iterative 10,11,12 -> 11 ± 1; ratio 11/3
    assert "| symbolic | 3 | 0, 1, 2 | 0.0400 ± 0.0200 | 3.000 ± 1.000 | 1.0 ± 0.0 | ×1 | ×1 |" in md
    assert "| iterative | 3 | 0, 1, 2 | 0.0800 ± 0.0400 | 11.000 ± 1.000 | 50.0 ± 0.0 | ×3.67 | ×50 |" in md
    for seed in REPORT_SEEDS:
        assert f"(symbolic_seed{seed}/report.html)" in md
        assert (fake_sweep / f"iterative_seed{seed}" / "report.html").is_file()
    html = (fake_sweep / "comparison.html").read_text()
    for src in _referenced_files(html, r'<img src="([^"]+)"'):
        assert (fake_sweep / src).stat().st_size > 100
    assert "comparison.md" in capsys.readouterr().out


@pytest.mark.slow
def test_comparison_of_run_dirs_with_out(fake_sweep, tmp_path):
    runs = [fake_sweep / "symbolic_seed0", fake_sweep / "iterative_seed2"]
    md_path, html_path = write_comparison(runs, out=tmp_path / "cmp")
    md = md_path.read_text()
    assert md_path.parent == tmp_path / "cmp" and html_path.is_file()
    assert "| symbolic | 1 | 0 | 0.0200 | 2.000 | 1.0 | ×1 | ×1 |" in md
    assert "(../sweep/symbolic_seed0/report.html)" in md


@pytest.mark.slow
def test_default_out_is_common_parent(fake_sweep):
    runs = [str(fake_sweep / "symbolic_seed0"), str(fake_sweep / "symbolic_seed1")]
    assert main(runs) == 0
    assert (Path(fake_sweep) / "comparison.html").is_file()


def test_minimal_results_json(tmp_path):
    run = tmp_path / "minimal"
    run.mkdir()
    (run / "results.json").write_text(json.dumps({
        "method": "lambertian_prior", "scene": "s", "channels": ["Y"],
        "parameters": [{"segment": "wall", "kernel": "mirror", "estimate": 0.5,
                        "reference": None, "error": None}],
        "cost_history": [3.0, 0.0, 0.0]}))
    md = write_run_report(run)[0].read_text()
    assert "| wall | mirror | — | 0.5000 | — |" in md
    assert "No views recorded." in md and (run / "report_files/convergence.png").is_file()


def test_correlation_of_many_parameters_is_a_table(tmp_path):
    """Above 24 parameters the report lists the strongest pairs instead of a heat map: with
    corr(p0, p1) = 0.9 and corr(p2, p3) = -0.95 set by hand, those two pairs come first."""
    run = make_fake_run(tmp_path / "run")
    res = json.loads((run / "results.json").read_text())
    n = 30
    matrix = np.eye(n)
    matrix[0, 1] = matrix[1, 0] = 0.9
    matrix[2, 3] = matrix[3, 2] = -0.95
    res["correlation"] = {"labels": [f"p{k}" for k in range(n)], "matrix": matrix.tolist()}
    (run / "results.json").write_text(json.dumps(res))
    md = write_run_report(run)[0].read_text()
    first, second = md.index("| p2 | p3 | -0.9500 |"), md.index("| p0 | p1 | 0.9000 |")
    assert first < second and "correlation.png" not in md


def test_illumination_and_vignetting_sections(tmp_path):
    """results.json ``illumination`` and ``vignetting`` become their own tables, each number with
    its standard error (fmt_num's four decimals)."""
    run = tmp_path / "survey"
    run.mkdir()
    (run / "results.json").write_text(json.dumps({
        "method": "symbolic", "scene": "s", "channels": ["R", "G", "B"],
        "parameters": [{"segment": "wall", "kernel": "diffuse", "estimate": [0.5] * 3}],
        "illumination": [{"emitter": 1, "part": "sun", "estimate": [1.12, 1.1, None], "std": [0.01, 0.02, None]}],
        "vignetting": [{"camera": 1, "known": False, "estimate": [-0.3, 0.0, 0.01], "std": [0.03, 0.1, 0.1],
                        "corner": 0.71, "corner_std": 0.02}]}))
    md = write_run_report(run)[0].read_text()
    assert "## Illumination" in md and "| 1 (sun) | 1.1200 ± 0.0100 | 1.1000 ± 0.0200 | — |" in md
    assert "## Vignetting" in md
    assert "| 1 | no | -0.3000 ± 0.0300 | 0.0000 ± 0.1000 | 0.0100 ± 0.1000 | 0.7100 ± 0.0200 |" in md


def test_excluded_pixels_map_and_legend(tmp_path):
    """results.json's ``excluded`` counts and ``excluded_map`` (framework.results.excluded_entry,
    codes by hand: 3 masked, 2 inconsistent, 1 outlier of 16 pixels) become a coloured map and a
    legend naming each reason with its count and colour."""
    from framework.results import excluded_entry
    from framework.scene.model import EXCLUSION_REASONS
    run = make_fake_run(tmp_path / "run", correlation=False)
    res = json.loads((run / "results.json").read_text())
    codes = np.zeros((4, 4), np.uint8)
    codes[0, :3] = EXCLUSION_REASONS.index("mask")
    codes[2, 1:3] = EXCLUSION_REASONS.index("inconsistent")
    codes[3, 3] = EXCLUSION_REASONS.index("outlier")
    entry = excluded_entry(run, "images/v0", codes)
    assert entry == {"excluded": {"mask": 3, "inconsistent": 2, "outlier": 1}, "excluded_map": "images/v0.excluded.png"}
    from PIL import Image
    assert np.array_equal(np.asarray(Image.open(run / entry["excluded_map"])), codes)
    res["views"][0].update(entry)
    (run / "results.json").write_text(json.dumps(res))
    md = write_run_report(run)[0].read_text()
    assert ("pixels left out and why: mask 3 (black), inconsistent 2 (red), outlier 1 (magenta); light grey: used"
            in md)
    drawn = [p for p in run.rglob("*_excluded.png")]
    assert len(drawn) == 1 and np.asarray(Image.open(drawn[0])).shape == (4, 4, 3)


@pytest.mark.parametrize("values, caption", [
    (np.ones((8, 8)), "pixel weight in the fit: every pixel had weight 1 (a plain white image)"),
    (np.r_[np.zeros(16), np.full(32, 0.5), np.ones(16)].reshape(8, 8),
     "pixel weight in the fit, black 0 (ignored or outlier) to white 1; here 0.000 to 1.000, median 0.500"),
])
def test_pixel_weight_caption(tmp_path, values, caption):
    """The weight panel says what its shades mean (was: "pixel weight in the fit (black: ignored
    or outlier)" under an empty white box when every weight was 1)."""
    from framework.images import write_exr
    run = make_fake_run(tmp_path / "run", correlation=False)
    write_exr(run / "images/v0.png.weights.exr", values.astype(np.float32)[..., None], ("Y",))
    res = json.loads((run / "results.json").read_text())
    res["views"][0]["weights"] = "images/v0.png.weights.exr"
    (run / "results.json").write_text(json.dumps(res))
    md = write_run_report(run)[0].read_text()
    assert caption in md


def test_where_the_time_went(tmp_path):
    """results.json's ``timings_s`` and ``solve_stages_s`` (numbers by hand) become a table of the
    method's time by part with its share, the rest as "other" (was: only render/solve/total, and a
    convergence plot spanning the last 2.5 s of a 192 s solve read as the whole)."""
    run = make_fake_run(tmp_path / "run", correlation=False)
    res = json.loads((run / "results.json").read_text())
    res["timings_s"].update(render=20.0, solve=70.0, method=100.0)
    res["solve_stages_s"] = {"psd": 1.0, "solver": 5.0, "uncertainty": 2.0, "field_setup": 4.0,
                             "weighted_systems": 8.0, "robust_weights": 20.0, "registration": 5.0,
                             "bias_refits": 20.0, "other": 5.0}
    res["cost_times_s"] = [97.5, 98.0, 100.0]
    (run / "results.json").write_text(json.dumps(res))
    md = write_run_report(run)[0].read_text()
    assert "### Where the time went" in md
    for row in ("| renders (the polynomial passes) | 20.00 | 20 % |",
                "| solver | 5.00 | 5 % |",
                "| photographs: robust reweighting | 20.00 | 20 % |",
                "| registration of the views (method.align) | 5.00 | 5 % |",
                "| finite-spp bias correction: the half-spp refits (method.bias) | 20.00 | 20 % |",
                "| other parts of the solve | 5.00 | 5 % |",
                "| outside the passes and the solve: prior, reconstructions, relighting, bookkeeping | 10.00 | 10 % |"):
        assert row in md, row
    assert "cost evaluations span 97.5–100.0 s after the method started (2.50 s)" in md


def test_fit_quality_table(tmp_path):
    """results.json ``fit_quality`` (numbers by hand) becomes a table, one row per material with
    its verdict and the largest factor its std was raised by (the pull's floor); a run without it
    (rendered observations) has no such table."""
    run = make_fake_run(tmp_path / "run", correlation=False)
    md = write_run_report(run)[0].read_text()
    assert "How well the model explains each material" not in md
    res = json.loads((run / "results.json").read_text())
    res["fit_quality"] = {"ground": {"pixels": 120, "dropped": 0.49, "chi2": 2.14, "poor": True,
                                     "why": "the robust weights left out 49 % of its pixels", "views": {},
                                     "pull": {"diffuse": [0.0433, 0.0349, 0.0271]},
                                     "pull_std": {"diffuse": [9.8, 10.0, 10.5]}},
                          "block": {"pixels": 80, "dropped": 0.063, "chi2": 0.756, "poor": False, "why": None,
                                    "views": {}, "pull": {"diffuse": [0.017, None, 0.0101]},
                                    "pull_std": {"diffuse": [1.1, None, -1.3]},
                                    "std_scale": {"diffuse": [1.0, 1.0, 1.0]}},
                          "wall": {"pixels": 900, "dropped": 0.02, "chi2": 0.9, "poor": False, "why": None,
                                   "views": {}, "pull": {"diffuse": [0.003, 0.0032, 0.0031]},
                                   "pull_std": {"diffuse": [2.3, 3.0, 3.6]},
                                   "std_scale": {"diffuse": [1.53, 2.0, 2.4]}},
                          "sky": {"pixels": 10, "dropped": 0.0, "chi2": 1.0, "poor": False, "why": None, "views": {}}}
    (run / "results.json").write_text(json.dumps(res))
    md = write_run_report(run)[0].read_text()
    assert "### How well the model explains each material" in md
    assert ("| ground | 120 | 49 % | 2.14 | +0.027 (10.5 std, diffuse B) | – | **poor**: the robust weights left "
            "out 49 % of its pixels |") in md
    assert "| block | 80 | 6 % | 0.76 | +0.010 (1.3 std, diffuse B) | – | explained |" in md
    assert "| wall | 900 | 2 % | 0.90 | +0.003 (3.6 std, diffuse B) | x2.4 | explained |" in md
    assert "| sky | 10 | 0 % | 1.00 | – | – | explained |" in md
