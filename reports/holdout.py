"""Held-out views in the reports: the run report's panel (photograph, prediction, difference,
metrics) and the comparison's table (one row per method, and the floor), from results.json
``holdout`` (docs/results.md)."""
from __future__ import annotations

import numpy as np

from reports.data import fmt_num, fmt_pm
from reports.doc import Doc
from reports.plots import image_pair

METRIC_COLUMNS = ["Pixels", "RMSE (mean over ch.)", "PSNR (dB)", "PSNR sRGB (dB)", "SSIM", "RMS z"]


def _rmse(entry: dict) -> float | None:
    """The mean over channels of an entry's per-channel RMSE."""
    values = [v for v in entry.get("rmse") or [] if v is not None]
    return float(np.mean(values)) if values else None


def _metric_cells(entry: dict) -> list[str]:
    return [str(entry.get("pixels", "—")), fmt_num(_rmse(entry)), fmt_num(entry.get("psnr"), digits=2),
            fmt_num(entry.get("psnr_srgb"), digits=2), fmt_num(entry.get("ssim"), digits=3),
            fmt_num(entry.get("z_rms"), digits=2)]


def _metrics_table(doc: Doc, entry: dict) -> None:
    """Whole view, its floor, and each segment."""
    rows = [["whole view"] + _metric_cells(entry)]
    if isinstance(entry.get("floor"), dict):
        rows.append(["floor (true reflectance)"] + _metric_cells(entry["floor"]))
    for name, seg in (entry.get("segments") or {}).items():
        rows.append([f"segment {name}"] + _metric_cells(seg))
    doc.table(["Region"] + METRIC_COLUMNS, rows,
              caption="Prediction at the estimate against the held-out photograph, over the pixels the run "
                      "would have used. RMS z: residuals in units of their predicted std (1 when it is honest). "
                      "Floor: the same metrics of a prediction at the scene's reference weights.")


def section_holdout(doc: Doc, ctx) -> None:
    """Each held-out view: its metrics, the photograph, the prediction and their difference."""
    entries = [e for e in (ctx.results.get("holdout") or []) if isinstance(e, dict)]
    if not entries:
        return
    doc.heading("Held-out views")
    for i, entry in enumerate(entries):
        name = str(entry.get("view", f"held-out {i}"))
        light = f" (under light {entry['light']}: relit)" if entry.get("light") else ""
        doc.heading(f"Held-out view {name}{light}", level=3)
        _metrics_table(doc, entry)
        paths = entry.get("images") or {}
        obs = ctx.load_image(paths.get("observed"), doc, "held-out photograph")
        pred = ctx.load_image(paths.get("prediction"), doc, "prediction")
        items = image_pair(ctx.out, f"holdout{i:02d}", obs, pred, ("photograph", "prediction"),
                           "prediction − photograph")
        if items:
            doc.figures(items)


def _view_mean(res: dict, getter) -> float | None:
    """Mean over a run's held-out views of ``getter(entry)`` (None when none gives a number)."""
    values = [getter(e) for e in res.get("holdout") or [] if isinstance(e, dict)]
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


def _floor(entry: dict) -> dict:
    return entry.get("floor") if isinstance(entry.get("floor"), dict) else {}


GETTERS = {"RMSE": _rmse, "PSNR (dB)": lambda e: e.get("psnr"), "PSNR sRGB (dB)": lambda e: e.get("psnr_srgb"),
           "SSIM": lambda e: e.get("ssim"), "RMS z": lambda e: e.get("z_rms")}


def section_holdout_table(doc: Doc, scene) -> None:
    """One row per method (mean ± std over its runs of the held-out views' means), the floor
    (the prediction at the true reflectance), and each method's RMSE over the floor's."""
    runs = [r for m in scene.methods for _, r in scene.by_method[m]]
    if not any(r.get("holdout") for r in runs):
        return
    doc.heading("Held-out views", level=3)
    floor = _view_mean_all(runs, lambda e: _rmse(_floor(e)))
    rows = []
    for m in scene.methods:
        cells = [fmt_pm(*scene.stat(m, lambda r, g=g: _view_mean(r, g)), digits=4) for g in GETTERS.values()]
        rmse = scene.stat(m, lambda r: _view_mean(r, _rmse))[0]
        ratio = f"{rmse / floor:.2f}x" if rmse is not None and floor else "—"
        rows.append([m] + cells + [ratio])
    if floor is not None:
        rows.append(["floor (true reflectance)"]
                    + [fmt_num(_view_mean_all(runs, lambda e, g=g: g(_floor(e))), digits=4) for g in GETTERS.values()]
                    + ["1.00x"])
    views = sorted({str(e.get("view")) for r in runs for e in r.get("holdout") or [] if isinstance(e, dict)})
    doc.table(["Method"] + list(GETTERS) + ["RMSE / floor"], rows,
              caption=f"Held-out view(s) {', '.join(views)}: each method's prediction at its estimate against the "
                      "photographs it never fitted (mean over held-out views, then mean ± std over runs). "
                      "Floor: the prediction at the scene's true reflectance, rendered alike: the best any "
                      "method can do.")


def _view_mean_all(runs, getter) -> float | None:
    """Mean over every run and held-out view of ``getter(entry)``."""
    values = [_view_mean(r, getter) for r in runs]
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None
