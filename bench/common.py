"""Shared helpers: composing configs, choosing views, error statistics."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from framework.config import BUNDLED_SCENES, compose
from framework.images import read_exr, write_exr
from framework.scene import load_scene
from framework.scene.write import write_colmap
from scenes.cameras import resized

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


def resized_copy(src: Path, dest: Path, image: int) -> Path:
    """``src`` copied to ``dest`` (replaced) with :func:`downsample_scene` at ``image`` pixels wide."""
    shutil.rmtree(dest, ignore_errors=True)
    shutil.copytree(src, dest, ignore=shutil.ignore_patterns("preview.png"))
    downsample_scene(src, dest, image)
    return dest
