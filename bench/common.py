"""Shared helpers: composing configs, choosing views, error statistics."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from framework.config import BUNDLED_SCENES, compose
from framework.images import read_exr, write_exr
from framework.scene import load_scene
from framework.scene.write import write_colmap, write_scene_yaml
from scenes.cameras import resized

#: sections whose figures are accuracies, not times (their wall times are shown, never a target):
#: with ``python -m bench --jobs N`` > 1 they run N at a time, after the others, which run alone;
#: longest first (2026-12-04, one at a time: survey 13.4, misfit 15.4, glossy 9.4, field 11.2,
#: defaults 4.5, holdout 3.5 min)
SHARED = ("survey", "misfit", "glossy", "field", "defaults", "holdout")

ROOT = Path(__file__).resolve().parents[1]


def view_names(scene_name: str, folder: Path | None = None) -> list[str]:
    """All camera names of a scene, the default view of config ``scene=<scene_name>`` first.

    ``folder``: the scene folder to read the cameras from (a ``scene.dir``); default the bundled
    folder ``scenes/<scene_name>``.
    """
    cfg = compose([f"scene={scene_name}"])
    names = [c.name for c in load_scene(Path(folder) if folder else BUNDLED_SCENES / scene_name).cameras]
    first = [v for v in cfg.scene.views if v in names]
    return first + [n for n in names if n not in first]


def views_override(scene_name: str, n: int, folder: Path | None = None) -> str:
    """``views=...`` override for the first ``n`` views (default view first); ``n = 0``: all.

    ``folder`` as in :func:`view_names`.
    """
    names = view_names(scene_name, folder)
    if n <= 0 or n >= len(names):
        return "views=all"
    return "views=[" + ",".join(names[:n]) + "]"


def seed_cache(src: Path, dst: Path) -> None:
    """Copy the observed images (only them) of cache ``src`` into the fresh cache ``dst``."""
    dst.mkdir(parents=True, exist_ok=True)
    if (src / "observed").is_dir():
        shutil.copytree(src / "observed", dst / "observed", dirs_exist_ok=True)


def param_errors(results: dict, keys: set | None = None) -> dict[tuple, list[float]]:
    """``(segment, kernel) -> [error per channel]`` of the observable parameters of a run.

    Parameters
    ----------
    results : dict
        A results dict (results.json).
    keys : set of (str, str), optional
        Only these parameters (e.g. the ones the symbolic run of the same views can observe).
    """
    out = {}
    for p in results["parameters"]:
        key = (p["segment"], p["kernel"])
        if p.get("error") is None or p.get("observable") is False or (keys is not None and key not in keys):
            continue
        out[key] = [float(e) for e in p["error"] if e is not None]
    return out


def error_stats(results: dict, keys: set | None = None) -> tuple[float, float]:
    """``(worst |error|, mean |error|)`` over observable parameters and channels (NaN if none)."""
    errs = [abs(e) for v in param_errors(results, keys).values() for e in v]
    if not errs:
        return float("nan"), float("nan")
    return float(max(errs)), float(np.mean(errs))


def observable_keys(results: dict) -> set:
    """The ``(segment, kernel)`` pairs a run reports as observable."""
    return {(p["segment"], p["kernel"]) for p in results["parameters"]
            if p.get("observable", True) and p.get("error") is not None}


def downsample_scene(src: Path, dest: Path, image: int) -> None:
    """The cameras of scene folder ``dest`` (a copy of ``src``) made ``image`` pixels wide, and its
    photographs (``images/<stem>.exr``, where present) box-averaged to match; a scene without
    photographs renders its observations at the new size. Views that all share one COLMAP camera
    (one lens) still do."""
    cams = load_scene(src).cameras
    shutil.rmtree(dest / "sparse")
    shared = len(cams) > 1 and len({c.camera_id for c in cams}) == 1      # one lens for every view: kept
    write_colmap(dest / "sparse", [resized(c, image) for c in cams], shared_camera=shared)
    for c in cams:
        path = dest / "images" / f"{Path(c.name).stem}.exr"
        if not path.is_file():
            continue
        k = c.width // image
        if k * image != c.width or c.height % k:
            raise ValueError(f"{c.name}: {c.width}x{c.height} does not box-downsample to {image} wide")
        img = read_exr(path)
        h, w, ch = img.shape
        write_exr(path, img.reshape(h // k, k, w // k, k, ch).mean((1, 3)))


def edited_copy(base: Path, dest: Path, desc: dict, comment: str) -> Path:
    """``base`` copied to ``dest`` (replaced) with scene.yaml ``desc`` (its first line ``comment``)."""
    shutil.rmtree(dest, ignore_errors=True)
    shutil.copytree(base, dest, ignore=shutil.ignore_patterns("preview.png"))
    write_scene_yaml(dest / "scene.yaml", desc, comment)
    return dest


def resized_copy(src: Path, dest: Path, image: int) -> Path:
    """``src`` copied to ``dest`` (replaced) with :func:`downsample_scene` at ``image`` pixels wide."""
    shutil.rmtree(dest, ignore_errors=True)
    shutil.copytree(src, dest, ignore=shutil.ignore_patterns("preview.png"))
    downsample_scene(src, dest, image)
    return dest


# ----------------------------------------------------------------------------------------------
# What a run got right (shared by the sections that judge results.json against a truth)
# ----------------------------------------------------------------------------------------------

Z, SLACK = 3.0, 0.005        # an error is beyond its std when |error| > Z std + SLACK


def determined_errors(results: dict) -> tuple[dict[str, list[float]], list[tuple], int]:
    """The errors of the determined weights (observable, not ill-determined, not known).

    Returns
    -------
    (errors, pairs, n_ill)
        ``errors``: kernel -> |error| per channel; ``pairs``: ``(error, std or None)`` per channel;
        ``n_ill``: observable weights the run called ill-determined (left out).
    """
    errs: dict[str, list[float]] = {"diffuse": [], "specular": []}
    pairs, n_ill = [], 0
    for p in results.get("parameters", []):
        if p.get("known") or p.get("error") is None or p.get("observable") is False:
            continue
        if p.get("ill_determined"):
            n_ill += 1
            continue
        for e, s in zip(p["error"], p.get("std") or [None] * len(p["error"])):
            if e is not None:
                errs.setdefault(p["kernel"], []).append(abs(e))
                pairs.append((e, s))
    return errs, pairs, n_ill


def z_stats(pairs: list[tuple]) -> dict:
    """``rms_z`` (RMS of error / std over the pairs with a positive std; None without any),
    ``n_z`` (their count) and ``beyond`` (pairs without a std or with |error| > Z std + SLACK)."""
    z = [e / s for e, s in pairs if s is not None and s > 0]
    beyond = sum(int(s is None or abs(e) > Z * s + SLACK) for e, s in pairs)
    return {"rms_z": float(np.sqrt(np.mean(np.square(z)))) if z else None, "n_z": len(z), "beyond": beyond}


def true_gains(folder: Path) -> dict[str, np.ndarray]:
    """View -> (C,) true gains from a scene's ``truth.yaml``."""
    import yaml
    truth = yaml.safe_load((Path(folder) / "truth.yaml").read_text())
    return {view: np.asarray(g, float) for view, g in truth["gains"].items()}


def gain_error(results: dict, gains: dict[str, np.ndarray]) -> float | None:
    """Worst |estimate / truth - 1| of results.json ``exposure`` over views and channels (None
    without per-view exposure)."""
    rel = [abs(e / t - 1) for x in results.get("exposure") or [] if x.get("estimate") and x["view"] in gains
           for e, t in zip(x["estimate"], gains[x["view"]]) if e is not None]
    return float(max(rel)) if rel else None


def failure(stderr: str, work: Path) -> str:
    """The line that says why a run wrote no results: the one-line ``error: ...`` of a refusal,
    else the exception's last line (a traceback's end), else the last line; the run folder
    ``work`` written ``<work>`` (the stored results name no machine's folders)."""
    lines = [x.strip() for x in stderr.splitlines() if x.strip()]
    refused = [x for x in lines if x.startswith("error:")]
    raised = [x for x in lines if x.split(":", 1)[0].endswith(("Error", "Exception"))]
    line = (refused or raised or lines or [""])[-1]
    return line.replace(str(work), "<work>")
