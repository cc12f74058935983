"""Section "holdout": every registered method predicts photographs it never fitted.

Two cases (:data:`CASES`), each fitted on some photographs of a scene and judged on others
(``holdout=[...]``: RMSE and PSNR on linear radiance, PSNR and SSIM on sRGB, the RMS of the
residuals over their predicted image-space std, ``docs/results.md``), against the **floor**: the
same prediction at the true reflectance (results.json ``holdout`` ``floor``), the best any method
can do with the photographs' noise and the model's light:

* ``street``: ``urban_canyon_field``, view :data:`HELD_STREET` held out, the other eight fitted;
* ``hour``: ``urban_canyon_survey``, its nine afternoon photographs fitted and the two of the
  morning (scene.yaml ``lights``) held out: the fit predicts the street under another sun
  (relighting).

Every method runs at the comparison section's settings (``render.spp`` ``sizes.cmp_spp``,
``observe.spp`` ``sizes.cmp_observe_spp``: the prediction's spp; budgets those of the
comparison's runs on all views, :func:`budget`) on a **variant every method can take**: the
baselines ``iterative`` and ``differentiable`` estimate no per-view gain, no light scale and no
lens, so

* ``street``: the field photographs with their true gains divided out (``truth.yaml``): linear EXR
  on the pinhole cameras as the loader resampled them, the unusable pixels (masked, clipped,
  outside) masked, ``exposure: known`` (:func:`gains_divided`);
* ``hour``: the survey photographs with the true lens falloff divided out and the light at its
  true scales (numbers), the panel an ordinary segment of reference 0.5 (:func:`light_given`).

What the section cuts to fit its time (:mod:`bench.sizes`, ``holdout_*``): the views are
``sizes.holdout_image`` pixels wide (the field scene built at that size by its generator, whose
JPEGs cannot be box-averaged; the survey's EXRs box-averaged), the baselines' budgets are divided
by ``sizes.holdout_budget_cut``, and the default method runs on the variants only, not on the
scenes as bundled: there its unknowns (the field's per-view gains; the survey's light scales and
lens) multiply the pass's monomials (256 on the street variant; 1781 with the field's gains, 2352
with the survey's scales and lens), and the solve's positive semi-definite projections, once per
robust reweighting round and refinement pass, with them: minutes of CPU at any image size
(measured once on the field at 50 pixels: 5.6 CPU minutes, 3.9 of them in the projections).
"""
from __future__ import annotations

import dataclasses
import functools
import shutil
import time
from pathlib import Path

import numpy as np
import yaml

from bench.common import compose, edited_copy, resized_copy, true_gains
from bench.tables import f, table, yes
from framework.errors import ConfigError, SceneError
from framework.images import read_exr, write_exr, write_png
from framework.registry import available_methods
from scenes import BUNDLED_DIR

FIELD, SURVEY = "urban_canyon_field", "urban_canyon_survey"
HELD_STREET = "street_004.jpg"
#: case -> (scene config, description); the held-out views of ``hour`` are the morning's
CASES = {"street": (FIELD, f"urban_canyon_field, {HELD_STREET} held out, the other 8 views fitted"),
         "hour": (SURVEY, "urban_canyon_survey, the 9 afternoon views fitted, the 2 morning views held out "
                          "(another sun: relighting)")}
#: the issue's targets for the default method: held-out RMSE within this factor of the floor's,
#: image-space RMS z in this range
RMSE_FACTOR, Z_RANGE = 1.1, (0.7, 1.5)
DEFAULT = "symbolic"


# ----------------------------------------------------------------------------------------------
# The scenes
# ----------------------------------------------------------------------------------------------

def field_folder(sizes, work: Path) -> Path:
    """The bundled field scene, or (``sizes.holdout_image`` not 200) the scene built at that size
    by its generator under ``work/scenes`` (built once)."""
    from scenes import urban_canyon_field
    if sizes.holdout_image in (None, urban_canyon_field.IMAGE):
        return BUNDLED_DIR / FIELD
    folder = work / "scenes" / f"{FIELD}_{sizes.holdout_image}"
    if not (folder / "truth.yaml").is_file():
        shutil.rmtree(folder, ignore_errors=True)
        urban_canyon_field.build(folder, image=sizes.holdout_image)
    return folder


def gains_divided(base: Path, dest: Path) -> Path:
    """``base`` (a field scene) with the true gains of ``truth.yaml`` divided out of its
    photographs: each view's linear image on its pinhole camera (as the loader resampled it) over
    its gains, as EXR; the pixels of weight 0 masked; ``exposure: known``, ``encoding`` and
    ``saturation`` left to the EXR defaults. What a method that estimates no gain can fit."""
    from framework.scene import load_scene
    from framework.scene.write import write_colmap
    scene = load_scene(base)
    gains = true_gains(base)
    desc = yaml.safe_load((base / "scene.yaml").read_text())
    desc.pop("photometry", None)
    folder = edited_copy(base, dest, desc, f"bench.holdout variant of {base.name}: the true gains divided out "
                                           "(see bench/holdout.py)")
    for sub in ("images", "masks", "sparse"):
        shutil.rmtree(folder / sub, ignore_errors=True)
    write_colmap(folder / "sparse", [dataclasses.replace(c, distortion=None) for c in scene.cameras])
    (folder / "masks").mkdir()
    (folder / "images").mkdir()
    for c in scene.cameras:
        write_exr(folder / "images" / f"{Path(c.name).stem}.exr", scene.images[c.name] / gains[c.name])
        used = np.ones((c.height, c.width)) if scene.weights is None else np.asarray(scene.weights[c.name])
        write_png(folder / "masks" / f"{c.name}.png", np.where(used > 0, 255, 0).astype(np.uint8))
    return folder


def survey_folder(sizes, work: Path, *, given: bool) -> Path:
    """The survey scene as bundled (``given=False``) or with the light and the lens given
    (:func:`light_given`), box-averaged to ``sizes.holdout_image`` pixels (built once)."""
    base = BUNDLED_DIR / SURVEY
    if given:
        base = light_given(base, work / "scenes" / f"{SURVEY}_given")
    if sizes.holdout_image in (None, 200):
        return base
    return resized_copy(base, work / "scenes" / f"{base.name}_{sizes.holdout_image}", sizes.holdout_image)


def light_given(base: Path, dest: Path) -> Path:
    """``base`` (the survey scene) with the true lens falloff divided out of every photograph and
    the afternoon light at its true scales (numbers); the panel an ordinary segment whose
    reference is its known value (:mod:`scenes.urban_canyon_survey`)."""
    from framework.scene import load_scene
    from scenes import urban_canyon_survey as survey
    from scenes.urban_canyon_glossy import write_half_exr
    desc = yaml.safe_load((base / "scene.yaml").read_text())
    desc["emitters"] = [survey.sunsky(sun_scale=survey.TRUE_SUN, sky_scale=survey.TRUE_SKY)]
    desc.pop("photometry", None)
    for seg in desc["segments"]:
        if seg["name"] == survey.PANEL_NAME:
            seg["reference"] = seg.pop("known")
    folder = edited_copy(base, dest, desc, f"bench.holdout variant of {SURVEY}: the light and the lens given "
                                           "(see bench/holdout.py)")
    for c in load_scene(base).cameras:
        path = folder / "images" / f"{Path(c.name).stem}.exr"
        factor = survey.falloff(survey.pixel_radius(c.width, c.height, c.cx, c.cy))
        write_half_exr(path, read_exr(path) / factor[..., None])
    return folder


def held_views(case: str, folder: Path) -> list[str]:
    """The views ``case`` holds out of the scene ``folder``."""
    if case == "street":
        return [HELD_STREET]
    from framework.scene import load_scene
    scene = load_scene(folder)
    return [c.name for c in scene.cameras if scene.light_of(c.name) is not None]


# ----------------------------------------------------------------------------------------------
# The runs
# ----------------------------------------------------------------------------------------------

def budget(sizes, method: str) -> int:
    """``budget.renders`` of ``method``: the comparison's on all views (section 3) divided by
    ``sizes.holdout_budget_cut`` for the baselines that render at every step."""
    if method == "differentiable":
        return max(2, sizes.cmp_budget_all_differentiable // sizes.holdout_budget_cut)
    if method == "iterative":
        return max(2, sizes.cmp_budget_all // sizes.holdout_budget_cut)
    return sizes.cmp_budget


def applicable(overrides, method: str) -> list[str]:
    """The ``method.*`` overrides of ``overrides`` that ``method``'s configuration has (the
    others unchanged): the quick sizes' solver and refinement settings reach the methods that
    have them."""
    keys = _method_keys(method)
    return [o for o in overrides if not o.startswith("method.") or o.split("=", 1)[0].split(".")[1] in keys]


@functools.lru_cache(maxsize=None)
def _method_keys(method: str) -> frozenset:
    """The top-level keys of ``method``'s composed configuration (composed once per method: a
    Hydra compose takes 0.2 s, and the section asks for each method on both cases)."""
    cfg = compose([f"method={method}"]).method
    return frozenset(k for k, v in cfg.items() if v is not None)


def run_one(sizes, work: Path, case: str, method: str, folder: Path, held: list[str], log=print) -> dict:
    """One run of ``method`` on ``case`` in this process: its row (the held-out views' metrics and
    the floor's, or the refusal), with its wall and CPU seconds."""
    from framework.experiment import run_experiment
    run_dir, cache = work / "runs" / case / method, work / "cache" / case / method
    for old in (run_dir, cache):
        shutil.rmtree(old, ignore_errors=True)
    overrides = [f"scene={CASES[case][0]}", f"scene.dir={folder}", "views=all", f"holdout=[{','.join(held)}]",
                 f"method={method}", f"render.spp={sizes.cmp_spp}", f"observe.spp={sizes.cmp_observe_spp}",
                 f"budget.renders={budget(sizes, method)}", "report=false", f"cache.dir={cache}",
                 *applicable([*sizes.extra, *sizes.holdout_extra], method)]
    row = {"case": case, "method": method, "budget": budget(sizes, method)}
    t, cpu = time.perf_counter(), time.process_time()
    try:
        res = run_experiment(compose(overrides), run_dir)
    except (ConfigError, SceneError) as exc:
        row.update(refusal=str(exc).replace(str(work), "<work>"), wall_s=time.perf_counter() - t,
                   cpu_s=time.process_time() - cpu)
        log(f"[holdout] {case} {method}: refused: {row['refusal']}")
        return row
    row.update(wall_s=time.perf_counter() - t, cpu_s=time.process_time() - cpu, renders=res["renders"],
               views=res["settings"]["views"], held=[{k: v for k, v in e.items() if k != "images"}
                                                     for e in res["holdout"]])
    row.update(summarise(res["holdout"]))
    log(f"[holdout] {case} {method}: RMSE {row['rmse']:.5f} (floor {row['floor_rmse']:.5f}), RMS z "
        f"{row['z_rms']}, {row['wall_s']:.0f} s")
    return row


def _mean(values) -> float | None:
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


def summarise(entries: list[dict]) -> dict:
    """Means over the held-out views (RMSE first averaged over channels) of a run's metrics and
    of its floor's, and the run's RMSE over the floor's."""
    out = {}
    for prefix, get in (("", lambda e: e), ("floor_", lambda e: e.get("floor") or {})):
        out[f"{prefix}rmse"] = _mean(_mean(get(e).get("rmse") or []) for e in entries)
        for key in ("psnr", "psnr_srgb", "ssim", "z_rms"):
            out[f"{prefix}{key}"] = _mean(get(e).get(key) for e in entries)
    out["ratio"] = out["rmse"] / out["floor_rmse"] if out["rmse"] and out["floor_rmse"] else None
    return out


def run(sizes, work: Path, log=print) -> dict:
    """Every registered method on each case's variant: ``{"settings": ..., "rows": [...]}``."""
    field = field_folder(sizes, work)
    folders = {"street": gains_divided(field, work / "scenes" / f"{field.name}_gains"),
               "hour": survey_folder(sizes, work, given=True)}
    rows = []
    for case, folder in folders.items():
        held = held_views(case, folder)
        rows += [run_one(sizes, work, case, method, folder, held, log=log) for method in available_methods()]
    settings = {"image": sizes.holdout_image, "spp": sizes.cmp_spp, "observe_spp": sizes.cmp_observe_spp,
                "budget_cut": sizes.holdout_budget_cut, "extra": [*sizes.extra, *sizes.holdout_extra]}
    return {"settings": settings, "rows": rows}


# ----------------------------------------------------------------------------------------------
# BENCHMARKS.md
# ----------------------------------------------------------------------------------------------

def targets(row: dict) -> bool:
    """The issue's targets for the default method: RMSE within :data:`RMSE_FACTOR` of the
    floor's, RMS z in :data:`Z_RANGE`."""
    return bool(row.get("ratio") is not None and row["ratio"] <= RMSE_FACTOR and row.get("z_rms") is not None
                and Z_RANGE[0] <= row["z_rms"] <= Z_RANGE[1])


def markdown(data: dict) -> list[str]:
    """Section 12: held-out views (:mod:`bench.holdout`), from :func:`run`'s record."""
    rows, st = data.get("rows") or [], data.get("settings") or {}
    if not rows:
        return []
    image = st["image"]
    lines = ["## 12. Held-out views: predicting photographs no method fitted", "",
             "Each method fits some photographs and predicts others it never saw (`holdout=[...]`): a street view "
             "of `urban_canyon_field`, and the two morning photographs of `urban_canyon_survey` (scene.yaml "
             "`lights`: the sun low, just north of east, where the fitted afternoon's is in the west-south-west; "
             "the prediction relights the street). The prediction is a `path` render at the estimate "
             f"({st['observe_spp']} spp), each view under its own light; the floor is the same prediction at the "
             "true reflectance, the residual no reflectance removes (the photographs' noise, the renderer's). "
             f"Section 3's settings (render.spp = {st['spp']}, observe.spp = {st['observe_spp']}, its budgets on "
             "all views), on a variant of each scene that every registered method can take (the baselines estimate "
             "no gain, light scale or lens): the field photographs with their true gains divided out (linear EXR "
             "on the pinhole cameras, the unusable pixels masked), the survey's with the light's true scales given "
             "and the lens falloff divided out (the panel an ordinary segment). Means over the held-out views; "
             "RMSE averaged over channels; RMS z: the residuals over their predicted image-space std (the delta "
             "method through the estimate's covariance, the photographs' noise taken as the fit's mean squared "
             "residual less its reconstructions' own Monte Carlo variance, the prediction's Monte Carlo noise; "
             "1 when honest). "
             f"Cut to fit the benchmark's time: views {image} pixels wide (the field scene built at that size by its "
             "generator, whose JPEGs cannot be box-averaged; the survey's photographs box-averaged); the iterative "
             f"and differentiable baselines' budgets divided by {st['budget_cut']} (they spend them all: their "
             "distance to the floor is at that budget); and no run of the default method on the scenes as bundled, "
             "whose unknowns (the field's per-view gains, the survey's light scales and lens) take the pass from "
             "256 monomials to 1781 and 2352, and the solve's positive semi-definite projections, once per robust "
             "round and refinement pass, to minutes of CPU at any image size. Targets (default method, both cases): "
             f"RMSE <= {RMSE_FACTOR} x the floor's, RMS z in [{Z_RANGE[0]}, {Z_RANGE[1]}].", ""]
    for case, (_, desc) in CASES.items():
        sub = [r for r in rows if r["case"] == case]
        if not sub:
            continue
        lines += [f"### {case}: {desc}", ""]
        body = []
        for r in sub:
            if "refusal" in r:
                body.append([r["method"], r["budget"], "n/a", f"refused: `{r['refusal']}`", "", "", "", "", "",
                             f(r["wall_s"], 1), f(r.get("cpu_s"), 1), "n/a"])
                continue
            mark = yes(targets(r)) if r["method"] == DEFAULT else "n/a"
            body.append([r["method"], r["budget"], r.get("renders"), f(r["rmse"], 5), f(r["ratio"], 2),
                         f(r["psnr"], 2), f(r["psnr_srgb"], 2), f(r["ssim"], 4), f(r["z_rms"], 2), f(r["wall_s"], 1),
                         f(r.get("cpu_s"), 1), mark])
        floor = next((r for r in sub if r["method"] == DEFAULT and r.get("floor_rmse") is not None), None)
        if floor is not None:
            body.append(["floor (true reflectance)", "", "", f(floor["floor_rmse"], 5), "1.00",
                         f(floor["floor_psnr"], 2), f(floor["floor_psnr_srgb"], 2), f(floor["floor_ssim"], 4),
                         f(floor["floor_z_rms"], 2), "", "", ""])
        lines += table(["method", "budget", "renders", "RMSE", "RMSE / floor", "PSNR (dB)", "PSNR sRGB (dB)", "SSIM",
                        "RMS z", "wall (s)", "CPU (s)", "targets"], body) + [""]
    walls, cpus = sum(r["wall_s"] for r in rows), sum(r.get("cpu_s") or 0.0 for r in rows)
    return lines + [f"The runs took {walls / 60:.1f} min wall, {cpus / 60:.1f} min CPU (the process's, all threads); the "
                    "section's wall time (above) adds building the scene variants.", ""]
