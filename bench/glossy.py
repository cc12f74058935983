"""Section "glossy": which kernel set do the photographs of ``urban_canyon_glossy`` prefer?

``urban_canyon_glossy`` (:mod:`scenes.urban_canyon_glossy`) is urban_canyon whose truth has
rough glass (window: ``glossy(0.05)`` 0.72) and satin walls (wall: ``glossy(0.3)`` 0.08), with its
photographs in the folder (``images/``, path traced at the truth). The symbolic method (in this
process, ``run_experiment``, default settings, all views) fits three models of the two glossy
segments -- window and wall get ``{diffuse, specular}``, ``{diffuse, glossy(α_true)}`` or
``{diffuse, specular, glossy(α_true)}``, every other segment keeps its true ``[diffuse,
specular]`` -- each a variant scene folder written into a temporary directory: the bundled
folder copied, ``scene.yaml``'s ``kernels`` rewritten per segment, references kept for the
kernels of the truth and 0 for the others (so the same ``images/`` are fitted every time).
Then an α sweep of the two glossy models: the window's α in ``sizes.glossy_alphas`` (walls at
their true α), one pass each (``method.refine=0``).

Per fit: the parameter count P (weights per channel: k = 3P), the worst and median |error| of
the diffuse weights (the weights every model shares; observable ones, all channels), the image
residual and a BIC-like criterion ``n ln(RSS / n) + k ln n`` with ``n`` the pixel-channel values
and ``RSS / n`` that residual: lower is better; with n ~ 10^5-10^6 it follows the residual unless
two fits' residuals differ by less than ~k ln(n) / n relative.

Which residual: results.json's ``image_rmse`` squared (the run's reconstructions: the pass's
polynomial at the estimate) is reported too, but it is dominated by the pass's own Monte Carlo
noise, which depends on the kernel set (a ``glossy(0.05)`` lobe sampled through next-event
estimation of the sun makes fireflies a mirror does not): on the quick size at 32 spp the true
model's was about twice the mirror model's, although its weights were 6x closer to the truth.
The criterion uses the *validation residual* instead (:func:`validation_residual`): two
independent Mitsuba ``path`` renders at the estimate, ``mean((A - obs)(B - obs))``, whose
expectation is the squared misfit of the expected image, render noise removed.

``--quick``: the views and photographs box-downsampled 200 -> 40 pixels (cameras rescaled with
:func:`scenes.cameras.resized`; a 5x5 box average of a box-filtered render is the render of the
coarser pixel), the sizes' ``glossy_spp`` and ``extra`` overrides. ``python -m bench.glossy
[--quick] [--out FILE]`` runs this section alone.
"""
from __future__ import annotations

import argparse
import json
import math
import re
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from bench.common import compose, downsample_scene
from bench.tables import f, table
from framework.config import BUNDLED_SCENES
from framework.experiment import run_experiment
from framework.brdf_kernels import canonical
from framework.scene import load_scene
from framework.scene.write import write_scene_yaml
from scenes import urban_canyon_glossy as ucg

SCENE = "urban_canyon_glossy"
GLOSSY_SEGMENTS = {"window": ucg.WINDOW_ALPHA, "wall": ucg.WALL_ALPHA}   # segment -> true α
#: (label, kernels of a glossy segment at roughness α)
MODELS = (("{diffuse, specular}", lambda a: ["diffuse", "specular"]),
          ("{diffuse, glossy(α)}", lambda a: ["diffuse", ucg.glossy_name(a)]),
          ("{diffuse, specular, glossy(α)}", lambda a: ["diffuse", "specular", ucg.glossy_name(a)]))
QUICK_IMAGE = 40
#: the full section's image width: 100x100 (the bundled 200x200 photographs box-downsampled 2x2)
#: keeps its 15 fits and their validation renders near 10 min on 2 cores
FULL_IMAGE = 100
#: samples per pixel of each of the two validation renders (:func:`validation_residual`)
VALIDATION_SPP = {"quick": 16, "default": 64}


def validation_spp(sizes) -> int:
    return VALIDATION_SPP.get(sizes.name, VALIDATION_SPP["default"])


# ----------------------------------------------------------------------------------------------
# Variant scene folders
# ----------------------------------------------------------------------------------------------
def model_kernels(model: int, window_alpha: float) -> dict[str, list[str]]:
    """Segment -> kernels of model ``model`` (index into :data:`MODELS`) with the window at
    ``window_alpha`` and the wall at its true α; segments not in :data:`GLOSSY_SEGMENTS`: None
    (their kernels as in the truth)."""
    alphas = {"window": window_alpha, "wall": GLOSSY_SEGMENTS["wall"]}
    return {seg: MODELS[model][1](alphas[seg]) for seg in GLOSSY_SEGMENTS}


def write_variant(src: Path, dest: Path, kernels_of: dict[str, list[str]], image: int | None = None) -> Path:
    """Copy scene folder ``src`` to ``dest`` with segment ``s``'s kernels ``kernels_of[s]``
    (segments not listed keep theirs) and references mapped from the truth: a kernel of the
    truth keeps its reference (names compared in canonical form), any other gets 0.

    ``image``: views and photographs box-downsampled to ``image`` pixels wide (a divisor of the
    width); None keeps them.
    """
    shutil.copytree(src, dest, ignore=shutil.ignore_patterns("preview.png"))
    desc = yaml.safe_load((src / "scene.yaml").read_text())
    for seg in desc["segments"]:
        kernels = kernels_of.get(seg["name"])
        if kernels is None:
            continue
        truth = {canonical(k): v for k, v in (seg.get("reference") or {}).items()}
        seg["kernels"] = list(kernels)
        seg["reference"] = {k: truth.get(canonical(k), 0.0) for k in kernels}
    write_scene_yaml(dest / "scene.yaml", desc, f"{SCENE} variant written by bench/glossy.py: "
                     + ", ".join(f"{s} {k}" for s, k in kernels_of.items()))
    if image is not None:
        downsample_scene(src, dest, image)
    return dest


# ----------------------------------------------------------------------------------------------
# Runs
# ----------------------------------------------------------------------------------------------
def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_")


def fit(sizes, folder: Path, run_dir: Path, overrides: list[str]) -> dict:
    """One symbolic run on ``folder`` (all views); its results dict."""
    cfg = compose(["method=symbolic", f"scene={SCENE}", f"scene.dir={folder}", "views=all",
                   f"render.spp={sizes.glossy_spp}", "report=false", "cache.dir=null", *sizes.extra, *overrides])
    return run_experiment(cfg, run_dir)


def validation_residual(folder: Path, res: dict, spp: int) -> tuple[float, int]:
    """``(residual, n)``: the mean over every pixel and channel of the selected views of
    ``(A - obs)(B - obs)``, ``A`` and ``B`` two independent Mitsuba ``path`` renders (unbounded
    depth, as the photographs) of the variant scene at the run's estimate (unobservable weights
    0), ``spp`` each; and ``n`` the pixel-channel values.

    Its expectation is the squared difference between the expected image at the estimate and
    the photographs, the render noise removed (the cross product of independent errors has mean
    0; the photographs' own noise remains, the same for every model). The seeds are the same for
    every fit (common random numbers), so differences between models are less noisy than the
    residuals themselves.
    """
    from framework.render.backend import set_variant
    from framework.render.mitsuba_scene import MitsubaScene

    scene = load_scene(folder)
    set_variant("auto", channels=scene.channels)
    cams = [c for c in scene.cameras if c.name in res["settings"]["views"]]
    params = scene.parameters()
    est = {(p["segment"], p["kernel"]): p.get("estimate") for p in res["parameters"]}
    rho = np.array([[0.0 if v is None else v for v in (est.get((p.segment_name, p.kernel)) or [0.0] * len(scene.channels))]
                    for p in params])
    ms = MitsubaScene(scene, cams, spp=spp, integrator={"type": "path", "max_depth": -1})
    ms.set_weights(rho, params)
    total, n = 0.0, 0
    for i, cam in enumerate(cams):
        obs = scene.images[cam.name].astype(np.float64)
        a = ms.render(i, spp=spp, seed=2 * (1000 + i) + 1) - obs
        b = ms.render(i, spp=spp, seed=2 * (2000 + i) + 1) - obs
        total += float(np.sum(a * b))
        n += obs.size
    return total / n, n


def row(label: str, model: int, alpha: float, res: dict, n: int, residual: float, wall_s: float) -> dict:
    """The table row of one run from its results dict, ``n`` pixel-channel values and its
    validation ``residual`` (:func:`validation_residual`)."""
    params = res["parameters"]
    diffuse = [abs(e) for p in params if p["kernel"] == "diffuse" and p.get("error") is not None
               and p.get("observable", True) for e in p["error"] if e is not None]
    pass_mse = res["image_rmse"] ** 2 if res.get("image_rmse") is not None else None
    k = len(params) * len(res["channels"])
    window = {canonical(p["kernel"]): p.get("estimate") for p in params if p["segment"] == "window"}
    window_std = {canonical(p["kernel"]): p.get("std") for p in params if p["segment"] == "window"}
    return {"label": label, "model": model, "alpha": alpha, "P": len(params), "k": k, "n": n, "mse": residual,
            "pass_mse": pass_mse, "bic": bic(residual, n, k), "diffuse_worst": max(diffuse) if diffuse else None,
            "diffuse_median": statistics.median(diffuse) if diffuse else None,
            "window": window, "window_std": window_std, "wall_s": wall_s, "renders": res["renders"], "error": None}


def bic(mse: float | None, n: int | None, k: int) -> float | None:
    """``n ln(RSS / n) + k ln n`` with ``RSS / n = mse`` (Gaussian residuals of unknown variance)."""
    if mse is None or not n or mse <= 0:
        return None
    return n * math.log(mse) + k * math.log(n)


def run_case(sizes, variants: Path, runs: Path, label: str, model: int, alpha: float, image, overrides,
             log=print) -> dict:
    """Write the variant of ``model`` at window α ``alpha``, fit it; a row (``error`` set if it raised)."""
    slug = _slug(f"{label}_{alpha}")
    try:
        folder = write_variant(BUNDLED_SCENES / SCENE, variants / slug, model_kernels(model, alpha), image)
        shutil.rmtree(runs / slug, ignore_errors=True)        # a fresh run folder, even in a reused work dir
        t = time.perf_counter()
        res = fit(sizes, folder, runs / slug, overrides)
        wall = time.perf_counter() - t
        residual, n = validation_residual(folder, res, validation_spp(sizes))
        out = row(label, model, alpha, res, n, residual, wall)
        log(f"[glossy] {label} α_window={alpha}: P {out['P']}, residual {residual:.4e} (pass {out['pass_mse']:.4e}), "
            f"diffuse worst {out['diffuse_worst']:.3f}, fit {wall:.1f} s")
        return out
    except Exception as exc:  # one failed fit must not lose the others
        log(f"[glossy] FAILED {label} α_window={alpha}: {exc!r}")
        return {"label": label, "model": model, "alpha": alpha, "error": repr(exc)[:300]}


def run(sizes, work: Path, log=print) -> dict:
    """The three models at the true α (default settings) and the α sweep (one pass each).

    Returns ``{"models": rows, "sweep": rows, "image": pixels wide, "spp": ...}``; also written
    to ``work/glossy.json``. Run folders go to ``work/runs``, variant scene folders to a
    temporary directory removed at the end.
    """
    work = Path(work)
    work.mkdir(parents=True, exist_ok=True)
    image = QUICK_IMAGE if sizes.name == "quick" else FULL_IMAGE
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="glossy_variants_") as tmp:
        variants = Path(tmp)
        models = [run_case(sizes, variants / "models", work / "runs" / "models", label, m, ucg.WINDOW_ALPHA,
                           image, [], log) for m, (label, _) in enumerate(MODELS)]
        sweep = [run_case(sizes, variants / "sweep", work / "runs" / "sweep", label, m, a, image, ["method.refine=0"],
                          log)
                 for m, (label, _) in enumerate(MODELS) if m > 0 for a in sizes.glossy_alphas]
    out = {"models": models, "sweep": sweep, "image": image or ucg.IMAGE, "spp": sizes.glossy_spp,
           "validation_spp": validation_spp(sizes),
           "extra": list(sizes.extra), "wall_s": time.perf_counter() - t0}
    (work / "glossy.json").write_text(json.dumps(out, indent=2))
    return out


# ----------------------------------------------------------------------------------------------
# Markdown
# ----------------------------------------------------------------------------------------------
def _ok(rows: list[dict]) -> list[dict]:
    return [r for r in rows if r.get("error") is None and r.get("bic") is not None]


def preferred(rows: list[dict]) -> dict | None:
    """The row of lowest criterion among the successful ones."""
    ok = _ok(rows)
    return min(ok, key=lambda r: r["bic"]) if ok else None


def markdown(out: dict) -> list[str]:
    """The section's markdown lines."""
    models, sweep = out["models"], out["sweep"]
    lines = ["## 8. Glossy kernels: which kernel set the photographs prefer", "",
             f"`{SCENE}` (urban_canyon with glossy truth: window `glossy(0.05)` 0.72, wall `glossy(0.3)` 0.08, "
             f"specular 0), its photographs path traced at the truth (unbounded depth, 1024 spp), all 9 views at "
             f"{out['image']}x{out['image']}, `method=symbolic` default settings, render.spp={out['spp']}"
             + (f", {' '.join(out['extra'])}" if out["extra"] else "") + ". The window and wall segments get the "
             "model's kernels, the other segments keep `[diffuse, specular]`; kernels outside the truth have "
             "reference 0. P: unknowns (k = 3P weights); diffuse |error|: worst and median over the diffuse "
             "weights of every segment and channel (the weights all models share); residual: validation "
             "residual, mean over every pixel and channel of (A - obs)(B - obs) with A, B two independent path "
             f"renders (unbounded depth, {out.get('validation_spp', 'n/a')} spp, the same seeds for every fit) at the "
             "estimate -- the squared misfit of the expected image, render noise removed; pass residual: "
             "results.json's image_rmse² (the pass's own reconstruction, dominated by its Monte Carlo noise, "
             "which depends on the kernels); criterion: BIC-like n ln(residual) + k ln n "
             "(n pixel-channel values; lower is better).", ""]
    body = []
    for r in models:
        if r.get("error"):
            body.append([r["label"], "failed", "", "", "", "", "", "", r["error"][:80]])
            continue
        w = r["window"]
        s = r.get("window_std") or {}
        kernels = ("diffuse", "specular", canonical(ucg.glossy_name(ucg.WINDOW_ALPHA)))
        cells = [_mean(w.get(k)) + (f" ± {_mean(s.get(k))}" if w.get(k) and s.get(k) else "") for k in kernels]
        body.append([r["label"], r["P"], f(r["diffuse_worst"], fmt=".3f"), f(r["diffuse_median"], fmt=".3f"), f(r["mse"], fmt=".4e"),
                     f(r["pass_mse"], fmt=".4e"), f(r["bic"], fmt=".0f"), " / ".join(cells), f(r["wall_s"], fmt=".1f")])
    lines += table(["model (window, wall)", "P", "diffuse worst", "diffuse median", "residual", "pass residual",
                     "criterion", "window ρ_d / ρ_s / ρ_g ± std (mean of channels; truth 0.18 / 0 / 0.72)",
                     "fit (s)"], body)
    best = preferred(models)
    if best:
        others = [r for r in _ok(models) if r is not best]
        gap = min((r["bic"] - best["bic"] for r in others), default=None)
        lines += ["", f"The data prefer **{best['label']}** (lowest criterion"
                  + (f", {gap:.0f} below the next" if gap is not None else "") + ")."]
    lines += ["", f"α sweep of the window (walls at α = {ucg.WALL_ALPHA}), one pass each (`method.refine=0`): "
              "validation residual (criterion) per window α.", ""]
    alphas = sorted({r["alpha"] for r in sweep})
    body = []
    for m, (label, _) in enumerate(MODELS):
        rows = [r for r in sweep if r["model"] == m]
        if not rows:
            continue
        by = {r["alpha"]: r for r in rows}
        cells = [f"{f(by[a].get('mse'), fmt='.4e')} ({f(by[a].get('bic'), fmt='.0f')})" if a in by else "n/a" for a in alphas]
        pick = preferred(rows)
        body.append([label] + cells + [f"{pick['alpha']}" if pick else "n/a"])
    lines += table(["model"] + [f"α = {a}" for a in alphas] + ["lowest residual at"], body)
    best = preferred(sweep)
    if best:
        lines += ["", f"Over the sweep the lowest criterion is {best['label']} at window α = {best['alpha']} "
                  f"(truth {ucg.WINDOW_ALPHA})."]
    lines += _one_pass_note(models, sweep)
    return lines + [""]


def _one_pass_note(models: list[dict], sweep: list[dict]) -> list[str]:
    """A line comparing, per model, the one-pass residual at the true α with the default fit's."""
    parts = []
    for m, (label, _) in enumerate(MODELS):
        full = next((r for r in _ok(models) if r["model"] == m), None)
        one = next((r for r in _ok(sweep) if r["model"] == m and r["alpha"] == ucg.WINDOW_ALPHA), None)
        if full and one:
            parts.append(f"{label} {one['mse']:.2e} in one pass against {full['mse']:.2e} with the default "
                         f"refinement ({full['renders']} renders)")
    if not parts:
        return []
    return ["", "At the true α, one pass (rendered at the guesses, 0.5: its kernel selection and the tail "
            "beyond N_max follow them) against the default fit, whose later passes are rendered at the estimate: "
            + "; ".join(parts) + ". The sweep ranks α by one pass each, a grid search; its residuals hold that "
            "difference."]


def _mean(v) -> str:
    vals = [x for x in (v or []) if x is not None]
    return f(float(np.mean(vals)), fmt=".3f") if vals else "–"


def main(argv=None) -> int:
    """``python -m bench.glossy [--quick] [--out FILE] [--work DIR]``: this section alone."""
    from bench.sizes import DEFAULT, QUICK
    p = argparse.ArgumentParser(prog="python -m bench.glossy", description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="toy sizes, to check the code paths")
    p.add_argument("--out", default=None, help="markdown file to write (default: stdout)")
    p.add_argument("--work", default=None, help="folder of the run folders (default: a temporary one)")
    args = p.parse_args(argv)
    sizes = QUICK if args.quick else DEFAULT
    log = lambda msg: print(f"{time.strftime('%H:%M:%S')} {msg}", file=sys.stderr, flush=True)  # noqa: E731
    with tempfile.TemporaryDirectory(prefix="bench_glossy_") as tmp:
        out = run(sizes, Path(args.work) if args.work else Path(tmp), log)
    text = "\n".join(markdown(out))
    if args.out:
        Path(args.out).write_text(text, encoding="utf-8")
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
