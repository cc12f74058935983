"""Section 2: peak memory and time of the symbolic method against the number of views and image size.

The bundled ``urban_canyon`` has nine 200x200 views; the runs here use variants of it with 15
street views and the aerial one (16 views) at each image size, built by
:func:`scenes.urban_canyon.build` into ``<work>/scenes/urban_canyon_v16_s<size>/`` and given as
``scene.dir``; a run on ``n`` views takes the first ``n`` (the default view first).

The runs are ``method=symbolic_paper`` (one pass: the default method repeats the pass up to four
times, one after the other, which changes its time, not its peak). Each configuration runs in its own subprocess (:mod:`bench.child` around
``python -m framework.run``), with a fresh empty ``cache.dir`` so nothing comes from a cache
(observations included: they are rendered inside the job and part of its time).
"""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

from bench.common import ROOT, views_override
from scenes import urban_canyon
from bench.tables import f, table

SCENE = "urban_canyon"


def run_child(overrides: list[str], timeout: float = 1800) -> dict:
    """Run :mod:`bench.child` with ``overrides``; returns its ``BENCH_CHILD`` dict."""
    proc = subprocess.run([sys.executable, "-m", "bench.child", *overrides], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout)
    for line in proc.stdout.splitlines():
        if line.startswith("BENCH_CHILD "):
            return json.loads(line[len("BENCH_CHILD "):])
    raise RuntimeError(f"bench.child failed (rc {proc.returncode}): {proc.stderr[-2000:]}")


def scene_variant(work: Path, n_views: int, image: int) -> Path:
    """The ``urban_canyon`` variant with ``n_views`` views (``n_views - 1`` street + aerial) of
    ``image`` x ``image`` pixels under ``work/scenes``, built once (reused if complete)."""
    folder = work / "scenes" / f"{SCENE}_v{n_views}_s{image}"
    if not (folder / "scene.yaml").is_file():
        if folder.exists():
            shutil.rmtree(folder)
        urban_canyon.build(folder, "rgb", n_street=n_views - 1, image=image)
    return folder


def measure(sizes, work: Path, n_views: int, image: int, executor: str = "serial") -> dict:
    """One symbolic run on the first ``n_views`` views (0: all) of the ``image``-pixel variant,
    in a fresh subprocess and fresh cache."""
    folder = scene_variant(work, sizes.mem_scene_views, image)
    n = n_views if 0 < n_views <= sizes.mem_scene_views else sizes.mem_scene_views
    tag = f"{executor}_v{n}_s{image}"
    cache, run_dir = work / "cache" / tag, work / "runs" / tag
    for old in (cache, run_dir):          # fresh and empty even when ``work`` is reused
        if old.exists():
            shutil.rmtree(old)
    overrides = ["method=symbolic_paper", f"scene={SCENE}", f"scene.dir={folder}", views_override(SCENE, n, folder),
                 f"render.spp={sizes.mem_spp}", f"observe.spp={sizes.mem_observe_spp}", "report=false",
                 f"cache.dir={cache}", f"hydra.run.dir={run_dir}",
                 f"executor={executor}", *sizes.extra]
    if executor == "dask":
        overrides += ["executor.n_workers=2", "executor.threads_per_worker=1"]
    out = run_child(overrides)
    res_path = run_dir / "results.json"
    res = json.loads(res_path.read_text()) if res_path.is_file() else {}
    return {"views": n, "image": image, "executor": executor, "scene_dir": str(folder), "rc": out["rc"],
            "wall_s": out["wall_s"], "maxrss_mib": out["maxrss_mib"], "tree_peak_mib": out["tree_peak_mib"],
            "timings_s": res.get("timings_s", {}), "error": None if out["rc"] == 0 else out["stderr_tail"]}


def plan(sizes) -> list[tuple[int, int, str]]:
    """``(views, image, executor)`` of every run: serial at each image size and view count, then Dask."""
    runs = [(n, s, "serial") for s in sizes.mem_images for n in sizes.mem_views]
    return runs + [(n, sizes.mem_dask_image, "dask") for n in sizes.mem_dask_views]


def run(sizes, work: Path, log=print) -> list[dict]:
    """All memory rows, in :func:`plan` order."""
    rows = []
    for n, image, executor in plan(sizes):
        rows.append(measure(sizes, work, n, image, executor))
        r = rows[-1]
        log(f"[memory] {executor} {r['views']} view(s) {image}x{image}: rc {r['rc']}, {r['wall_s']:.1f} s, "
            f"peak RSS {r['maxrss_mib']:.0f} MiB, tree {r['tree_peak_mib']:.0f} MiB")
    return rows


# ----------------------------------------------------------------------------------------------
# BENCHMARKS.md
# ----------------------------------------------------------------------------------------------

def markdown(rows: list[dict], sizes) -> list[str]:
    lines = ["## 2. Peak memory of the symbolic method vs number of views and image size", "",
             f"`python -m framework.run method=symbolic scene=urban_canyon scene.dir=<variant> views=<first n> "
             f"render.spp={sizes.mem_spp} observe.spp={sizes.mem_observe_spp} report=false`, serial and with "
             "`executor=dask executor.n_workers=2 executor.threads_per_worker=1`. The variant is urban_canyon "
             f"with {sizes.mem_scene_views - 1} street views and the aerial one ({sizes.mem_scene_views} views; "
             "`scenes.urban_canyon.build(folder, n_street=..., image=...)`, same geometry and light) at each "
             "image size, built into the benchmark's work folder; a run on n views takes the first n: the "
             "default view street_002, then in name order (aerial_000, street_000, ...). Each run is in a "
             "fresh subprocess (`bench.child`) with a fresh empty cache.dir (observations rendered inside the "
             "job). "
             "Peak RSS: `getrusage(RUSAGE_CHILDREN).ru_maxrss` of the wrapper after the job exits (the "
             "largest single process); tree peak: the largest sampled sum of RSS over the job and its "
             "descendants (Dask workers included; sampled every 0.1 s). Target: flat in the number of views.", ""]
    body = [[r["views"], f"{r['image']}x{r['image']}", r["executor"], r["rc"], f(r["wall_s"], 1),
             f(r["timings_s"].get("render"), 1), f(r["timings_s"].get("solve"), 2), f(r["maxrss_mib"], 0),
             f(r["tree_peak_mib"], 0)] for r in rows]
    lines += table(["views", "image", "executor", "exit", "wall (s)", "pass (s)", "solve (s)", "peak RSS (MiB)",
                    "tree peak (MiB)"], body)
    growth = _memory_growth(rows)
    if growth:
        lines += ["", "Serial peak RSS from the fewest to the most views: " + "; ".join(growth) + "."]
    return lines + [""]


def _memory_growth(rows: list[dict]) -> list[str]:
    """Per image size, the serial peak-RSS change from the fewest to the most views (successful runs)."""
    out = []
    for image in sorted({r["image"] for r in rows}):
        ok = sorted((r["views"], r["maxrss_mib"]) for r in rows
                    if r["executor"] == "serial" and r["image"] == image and r["rc"] == 0)
        if len(ok) < 2 or ok[0][0] == ok[-1][0]:
            continue
        (n0, m0), (n1, m1) = ok[0], ok[-1]
        out.append(f"{image}x{image}: {100 * (m1 / m0 - 1):+.0f} % ({m0:.0f} MiB at {n0} view"
                   f"{'s' if n0 > 1 else ''} to {m1:.0f} MiB at {n1})")
    return out
