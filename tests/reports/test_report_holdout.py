"""reports: held-out views (results.json ``holdout``) in the run report and the comparison table,
from fake run folders with known numbers."""
import json
import re

from fakes import make_fake_run

from reports import write_comparison, write_run_report


def _metrics(rmse, z, pixels=100):
    return {"pixels": pixels, "rmse": rmse, "psnr": 30.0, "psnr_srgb": 35.0, "ssim": 0.9, "z_rms": z}


def _add_holdout(run, rmse, z):
    """A held-out view v1.png of the fake run: its photograph the fake observed image, its
    prediction the fake reconstruction; floor RMSE 0.01 in every channel."""
    res = json.loads((run / "results.json").read_text())
    res["holdout"] = [{"view": "v1.png", **_metrics(rmse, z), "segments": {"wall": _metrics(rmse, z, 60)},
                       "floor": {**_metrics([0.01] * 3, 1.0), "segments": {}},
                       "images": {"observed": "images/v0.png.observed.exr",
                                  "prediction": "images/v0.png.reconstruction.exr"}}]
    (run / "results.json").write_text(json.dumps(res))
    return run


def test_run_report_holdout_panel(tmp_path):
    run = _add_holdout(make_fake_run(tmp_path / "run"), [0.02, 0.03, 0.04], 1.2)
    md_path, html_path = write_run_report(run)
    md = md_path.read_text()
    assert "### Held-out view v1.png" in md
    assert "| whole view | 100 | 0.0300 | 30.00 | 35.00 | 0.900 | 1.20 |" in md
    assert "| floor (true reflectance) | 100 | 0.0100 |" in md and "| segment wall | 60 | 0.0300 |" in md
    srcs = [s for s in re.findall(r'<img src="([^"]+)"', html_path.read_text()) if "holdout" in s]
    assert len(srcs) == 3                                  # photograph, prediction, difference
    for src in srcs:
        assert (run / src).stat().st_size > 100, src


def test_comparison_holdout_table(tmp_path):
    """One row per method (mean ± std over seeds), the floor, each method's RMSE over it."""
    for seed, rmse in ((0, 0.02), (1, 0.04)):
        _add_holdout(make_fake_run(tmp_path / f"symbolic_seed{seed}", seed=seed), [rmse] * 3, 1.0)
    _add_holdout(make_fake_run(tmp_path / "iterative_seed0", method="iterative"), [0.05] * 3, None)
    md = write_comparison([tmp_path])[0].read_text()
    assert "| symbolic | 0.0300 ± 0.0141 | 30.0000 ± 0.0000 |" in md and md.count("| 3.00x |") == 1
    assert "| iterative | 0.0500 | 30.0000 | 35.0000 | 0.9000 | — | 5.00x |" in md
    assert "| floor (true reflectance) | 0.0100 | 30.0000 | 35.0000 | 0.9000 | 1.0000 | 1.00x |" in md
