"""results.json (``docs/results.md``) and the run folder's images."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from framework.cache import atomic_write_bytes
from framework.images import write_exr
from framework.registry import MethodResult, Problem


def _listify(row: np.ndarray) -> list | None:
    """One number per channel, None for NaN (unknown) entries; None if all unknown."""
    if row is None or np.all(np.isnan(row)):
        return None
    return [None if np.isnan(x) else float(x) for x in row]


def parameter_rows(problem: Problem, result: MethodResult) -> list[dict]:
    params = result.parameters or problem.parameters
    ref = problem.scene.reference(params)
    rows = []
    for p in params:
        est = result.estimate[p.index]
        observable = True if result.observable is None else bool(result.observable[p.index])
        row = {"segment": p.segment_name, "kernel": p.kernel,
               "estimate": _listify(est) if observable else None,
               "reference": _listify(ref[p.index]),
               "error": _listify(est - ref[p.index]) if observable else None}
        if result.std is not None:
            row["std"] = _listify(result.std[p.index]) if observable else None
        if result.observable is not None:
            row["observable"] = observable
        rows.append(row)
    return rows


def image_rmse(problem: Problem, result: MethodResult) -> float | None:
    """RMSE over every pixel and channel of every view with a reconstruction."""
    sq, n = 0.0, 0
    for name, rec in result.reconstructions.items():
        d = rec.astype(float) - problem.observed[name]
        sq, n = sq + float((d * d).sum()), n + d.size
    return float(np.sqrt(sq / n)) if n else None


def write_view_images(run_dir: Path, problem: Problem, result: MethodResult, segment_maps: dict) -> list[dict]:
    """Observed / reconstruction EXRs and segment maps under ``images/``; their entries for results.json."""
    entries = []
    (run_dir / "images").mkdir(parents=True, exist_ok=True)
    for cam in problem.cameras:
        base = f"images/{cam.name}"
        write_exr(run_dir / f"{base}.observed.exr", problem.observed[cam.name], problem.scene.channels)
        entry = {"name": cam.name, "observed": f"{base}.observed.exr", "reconstruction": None, "segments": None}
        if cam.name in result.reconstructions:
            write_exr(run_dir / f"{base}.reconstruction.exr", result.reconstructions[cam.name],
                      problem.scene.channels)
            entry["reconstruction"] = f"{base}.reconstruction.exr"
        if cam.name in segment_maps:
            np.save(run_dir / f"{base}.segments.npy", segment_maps[cam.name].astype(np.int32))
            entry["segments"] = f"{base}.segments.npy"
        entries.append(entry)
    return entries


def write_relit_images(run_dir: Path, problem: Problem, result: MethodResult) -> list[dict]:
    """Relit and reflectance images a method returned in ``extras["relit_images"]`` (popped):
    EXRs under ``images/`` and the ``relit`` entries of results.json."""
    images = result.extras.pop("relit_images", None) or {}
    entries = []
    for name, image in images.items():
        path = f"images/{name}.exr"
        write_exr(run_dir / path, image, problem.scene.channels)
        entries.append({"name": name, "image": path})
    return entries


def results_dict(problem: Problem, result: MethodResult, *, method: str, settings: dict,
                 views: list[dict], relit: list[dict]) -> dict:
    return {
        "method": method,
        "scene": problem.scene.name,
        "channels": list(problem.scene.channels),
        "parameters": parameter_rows(problem, result),
        "timings_s": {k: float(v) for k, v in result.timings_s.items()},
        "renders": int(result.renders),
        "cost_history": [float(c) for c in result.cost_history],
        "cost_times_s": [float(t) for t in result.cost_times_s],
        "trace": result.trace,
        "image_rmse": image_rmse(problem, result),
        "settings": settings,
        "segments": [s.name for s in problem.scene.segments],
        "views": views,
        "relit": relit,
        **result.extras,
    }


def write_results(run_dir: Path, results: dict) -> Path:
    """Write results.json atomically: it appears whole or not at all."""
    path = Path(run_dir) / "results.json"
    atomic_write_bytes(path, (json.dumps(results, indent=2, allow_nan=False) + "\n").encode())
    return path
