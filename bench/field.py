"""Section "field": the symbolic method on photographs as a camera delivers them.

Scene ``urban_canyon_field`` (``python -m scenes.build urban_canyon_field``; its README lists
what was done to the clean street: OPENCV and SIMPLE_RADIAL distortion, per-view gains, sensor
noise, 8-bit sRGB JPEG with clipped highlights, a masked car and an unmasked pedestrian that the
model lacks). All views, default settings, then the same photographs with one part of the field
path switched off at a time, so the gain from each part shows:

* naive: exposure taken as known (gains 1), no pixel weights (masks, saturation ignored), plain L2;
* + exposure: per-view gains estimated;
* + masks: the scene's pixel weights (masks, saturated and clipped pixels out);
* default: + robust Cauchy reweighting (``method.robust=auto``);
* the default without leaving out the pixels next to a change of segment (``method.boundary=0``);
* the default with each pixel rendered over its own box (``method.footprint=pixel``) instead of
  over the source pixels the loader's interpolation weighs: the blur the resampling adds to the
  photographs is then missing from the model's pixels and trades the window's mirror weight for
  its diffuse one (measured before the footprint, window ρ_d / ρ_s averaged over channels: the
  same scene from pinhole cameras, no resampling, +0.012 / -0.018; those photographs blurred by
  a Gaussian of 0.41 px, the mean blur of bilinear interpolation, +0.018 / -0.026; the distorted
  photographs resampled bilinearly +0.022 / -0.034);
* the default on a copy of the scene whose ``photometry`` resamples the distorted photographs by
  Keys' cubic convolution instead of bilinear interpolation (``resampling: cubic``), both with
  the footprint and without it;
* the default with the pixel sandwich std (``method.std=sandwich``), without the finite-spp
  bias correction (``method.bias=none``), without the views' alignment (``method.align=none``;
  the scene's poses are right, so this row shows what aligning right cameras costs).

Targets (default row): every parameter the run calls determined within 0.03 (diffuse) / 0.05
(specular) of its reference, every gain within 3 % of the truth (``truth.yaml`` of the scene).
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from bench.common import determined_errors, edited_copy, gain_error, true_gains, z_stats
from bench.memory import run_child
from scenes import BUNDLED_DIR
from bench.tables import f, table, yes

SCENE = "urban_canyon_field"
DIFFUSE_TOL, SPECULAR_TOL, GAIN_TOL = 0.03, 0.05, 0.03
VARIANTS = (  # label, overrides[, the scene's photometry changed in a copy of it]
    ("naive (gains 1, every pixel, L2)", ["method.exposure=known", "method.weights=none", "method.robust=none"]),
    ("+ per-view exposure", ["method.weights=none", "method.robust=none"]),
    ("+ masks and saturation", ["method.robust=none"]),
    ("default (+ robust Cauchy, cluster std, bias correction, alignment)", []),
    ("default without the boundary exclusion", ["method.boundary=0"]),
    ("default, each pixel its own box (footprint=pixel)", ["method.footprint=pixel"]),
    ("default, photographs resampled by cubic convolution", [], {"resampling": "cubic"}),
    ("cubic convolution, each pixel its own box", ["method.footprint=pixel"], {"resampling": "cubic"}),
    ("default, pixel sandwich std (method.std=sandwich)", ["method.std=sandwich"]),
    ("default without the bias correction (method.bias=none)", ["method.bias=none"]),
    ("default without the alignment (method.align=none)", ["method.align=none"]),
)


def summarise(res: dict, gains: dict[str, np.ndarray]) -> dict:
    """Worst and median |error| of the determined parameters per kernel, worst relative gain error."""
    errs = {"diffuse": [], "specular": []}
    for p in res.get("parameters", []):
        if p.get("error") is None or p.get("ill_determined", False) or p["kernel"] not in errs:
            continue
        errs[p["kernel"]] += [abs(e) for e in p["error"] if e is not None]
    gain_err = gain_error(res, gains)
    worst = {k: max(v) if v else None for k, v in errs.items()}
    met = bool(worst["diffuse"] is not None and worst["diffuse"] <= DIFFUSE_TOL
           and (worst["specular"] is None or worst["specular"] <= SPECULAR_TOL)
           and gain_err is not None and gain_err <= GAIN_TOL)
    n_ill = sum(bool(p.get("ill_determined")) for p in res.get("parameters", []))
    return {"worst_diffuse": worst["diffuse"], "worst_specular": worst["specular"],
            "median": float(np.median(errs["diffuse"] + errs["specular"])) if errs["diffuse"] else None,
            "gain_error": gain_err, "ill_determined": n_ill, "met": met, "image_rmse": res.get("image_rmse"),
            "renders": res.get("renders"), "irls": (res.get("field") or {}).get("irls_stopped"),
            **z_stats(determined_errors(res)[1])}


def scene_folder(sizes, work: Path) -> Path:
    """The bundled folder, or (``sizes.field_image``) the scene built at that size by its generator
    under ``work/scenes`` (its JPEG photographs cannot be box-averaged)."""
    if sizes.field_image is None:
        return BUNDLED_DIR / SCENE
    from scenes import urban_canyon_field
    folder = work / "scenes" / f"{SCENE}_{sizes.field_image}"
    shutil.rmtree(folder, ignore_errors=True)
    return urban_canyon_field.build(folder, image=sizes.field_image)


def run(sizes, work: Path, log=print) -> list[dict]:
    """The variants of :data:`VARIANTS` that ``sizes.field_rows`` keeps; a row dict each."""
    folder = scene_folder(sizes, work)
    gains = true_gains(folder)
    rows = []
    for label, overrides, *photometry in VARIANTS:
        if sizes.field_rows is not None and label not in sizes.field_rows:
            continue
        tag = "".join(ch if ch.isalnum() else "_" for ch in label)[:24]
        run_dir = work / "runs" / f"{len(rows)}_{tag}"
        shutil.rmtree(run_dir, ignore_errors=True)
        copy = _copy_with(folder, work / "scenes" / tag, photometry[0]) if photometry else folder
        scene = f"scene.dir={copy}"
        out = run_child([f"scene={SCENE}", scene, "views=all", "method=symbolic", *overrides, "report=false",
                         f"cache.dir={work / 'cache' / tag if photometry else work / 'cache'}",
                         f"hydra.run.dir={run_dir}", *sizes.extra, *sizes.field_extra], timeout=3600)
        path = run_dir / "results.json"
        res = json.loads(path.read_text()) if path.is_file() else {}
        row = {"label": label, "rc": out["rc"], "wall_s": out["wall_s"], "maxrss_mib": out["maxrss_mib"],
               "image": sizes.field_image}
        row.update(summarise(res, gains) if res else {"met": False, "error": out["stderr_tail"][-300:]})
        rows.append(row)
        log(f"[field] {label}: worst diffuse {row.get('worst_diffuse')}, specular {row.get('worst_specular')}, "
            f"gain error {row.get('gain_error')}, {out['wall_s']:.0f} s")
    return rows


def _copy_with(folder: Path, to: Path, photometry: dict) -> Path:
    """A copy of the scene ``folder`` at ``to`` whose scene.yaml ``photometry`` has ``photometry``'s
    entries (the bundled scene stays as it is)."""
    import yaml
    spec = yaml.safe_load((folder / "scene.yaml").read_text())
    spec["photometry"] = {**spec.get("photometry", {}), **photometry}
    return edited_copy(folder, to, spec, f"bench.field variant of {SCENE} (see bench/field.py)")


# ----------------------------------------------------------------------------------------------
# BENCHMARKS.md
# ----------------------------------------------------------------------------------------------

def markdown(rows: list[dict]) -> list[str]:
    """Section 7: field photographs (:mod:`bench.field`)."""
    if not rows:
        return []
    image = rows[0].get("image")      # the width the scene was built at (None: the bundled 200)
    lines = ["## 7. Field photographs (urban_canyon_field, all views)", "",
             "Distorted cameras (OPENCV, SIMPLE_RADIAL), 8-bit sRGB JPEG with clipped highlights, per-view gains, "
             "sensor noise, a masked car and an unmasked pedestrian the model lacks (the scene's README). The first "
             "rows switch on one more part of the field path each; then the default with one change: no boundary "
             "exclusion; each pixel rendered over its own box (`method.footprint=pixel`) instead of over the source "
             "pixels the loader's interpolation weighs, so the resampling's blur is missing from the model (it trades "
             "the window's mirror weight for its diffuse one); the photographs resampled by Keys' cubic convolution "
             "(`photometry: resampling: cubic`), with and without the footprint; the pixel sandwich std instead of "
             "the cluster-robust one; no finite-spp bias correction (`method.bias=none`: the estimate as solved, "
             "not extrapolated from the pass's half-spp refits); no alignment of the views between the passes "
             "(`method.align=none`; this scene's poses are right). Only the rows in the table were run at these sizes "
             "(`Sizes.field_rows`). On photographs the cluster std, the bias "
             "correction and the alignment are the defaults (`auto`), so they are on from the row with per-view "
             "exposure. "
             "Errors over the parameters the run "
             "calls determined; gain error relative to the truth; RMS z and the count beyond 3 std + 0.005 over the "
             "determined weights' channels. Targets (default row): 0.03 diffuse, 0.05 specular, gains 3 %."
             + (f" The scene is built by its generator (`scenes.urban_canyon_field.build`, same seed) at {image} "
                "pixels wide instead of the bundled 200: at the bundled size the section's 11 rows took 40 min "
                "on this 2-core machine (2026-12-04), beyond the hour the whole benchmark has; errors and z "
                "are those of the smaller photographs." if image else ""), ""]
    body = [[r["label"], f(r.get("worst_diffuse"), 4), f(r.get("worst_specular"), 4), f(r.get("median"), 4),
             f(100 * r["gain_error"], 2) if r.get("gain_error") is not None else "n/a (gains 1)",
             r.get("ill_determined"), f(r.get("image_rmse"), 5), f(r.get("rms_z"), 2),
             f"{r['beyond']} / {r['n_z']}" if r.get("n_z") else "n/a", r.get("renders"), f(r["wall_s"], 1), yes(r["met"])]
            for r in rows]
    return lines + table(["fit", "worst diffuse", "worst specular", "median", "worst gain error (%)",
                          "ill-determined", "image RMSE", "RMS z", "beyond 3 std + 0.005", "renders", "wall (s)",
                          "targets"], body) + [""]
