"""Section 5: the symbolic method against the number of materials.

``scenes.street_block`` cuts the urban canyon's facades into K buildings per side, each with its
own materials (same street, same 9 views): D = 2 x materials weights. Each K runs once in a fresh
subprocess (peak RSS measured by :mod:`bench.child`) with a fresh cache, on all views, with
``method=symbolic_paper`` (one pass: the growth of the pass, the system and the solve in D; the
default method repeats both up to 4 times).
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from bench.memory import run_child
from scenes import street_block


def measure(sizes, work: Path, buildings: int) -> dict:
    """One symbolic run on ``street_block`` with ``buildings`` per side; a row dict."""
    folder = work / "scenes" / f"street_k{buildings}_s{sizes.mat_image}"
    if not (folder / "scene.yaml").is_file():
        shutil.rmtree(folder, ignore_errors=True)
        street_block.build(folder, buildings=buildings, image=sizes.mat_image)
    cache, run_dir = work / "cache" / f"k{buildings}", work / "runs" / f"k{buildings}"
    for old in (cache, run_dir):
        shutil.rmtree(old, ignore_errors=True)
    out = run_child(["method=symbolic_paper", f"scene.dir={folder}", "views=all", f"render.spp={sizes.mem_spp}",
                     f"observe.spp={sizes.mem_observe_spp}", "report=false", f"cache.dir={cache}",
                     f"hydra.run.dir={run_dir}", *sizes.extra], timeout=sizes.mat_timeout_s)
    path = run_dir / "results.json"
    res = json.loads(path.read_text()) if path.is_file() else {}
    errs = [abs(e) for p in res.get("parameters", []) if p.get("error") is not None
            and not p.get("ill_determined", False) for e in p["error"]]
    return {"buildings": buildings, "materials": len(res.get("segments", [])) or None,
            "D": len(res.get("parameters", [])) or None, "rc": out["rc"], "wall_s": out["wall_s"],
            "maxrss_mib": out["maxrss_mib"], "monomials": res.get("n_monomials"), "gram_nnz": res.get("gram_nnz"),
            "pass_s": res.get("timings_s", {}).get("render"), "solve_s": res.get("timings_s", {}).get("solve"),
            "worst": max(errs) if errs else None, "median": float(np.median(errs)) if errs else None,
            "psd_skipped": res.get("psd_skipped_components"),
            "error": None if out["rc"] == 0 else out["stderr_tail"][-300:]}


def growth_law(rows: list[dict], key: str) -> tuple[float, float] | None:
    """``(a, b)`` of the least-squares fit ``key = a · D^b`` over the successful rows (None if < 2)."""
    pts = [(r["D"], r[key]) for r in rows if r["rc"] == 0 and r.get(key) and r.get("D")]
    if len(pts) < 2:
        return None
    b, log_a = np.polyfit(np.log([d for d, _ in pts]), np.log([v for _, v in pts]), 1)
    return float(np.exp(log_a)), float(b)


def run(sizes, work: Path, log=print) -> list[dict]:
    rows = []
    for k in sizes.mat_buildings:
        rows.append(measure(sizes, work, k))
        r = rows[-1]
        log(f"[materials] K={k}: rc {r['rc']}, D {r['D']}, {r['wall_s']:.1f} s, peak {r['maxrss_mib']:.0f} MiB")
    return rows
