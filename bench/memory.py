"""Section 2: peak memory and time of the symbolic method at 1, 4 and all views.

Each configuration runs in its own subprocess (:mod:`bench.child` around
``python -m framework.run``), with a fresh empty ``cache.dir`` so nothing comes from a cache
(observations included: they are rendered inside the job and part of its time).
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from bench.common import ROOT, view_names, views_override


def run_child(overrides: list[str], timeout: float = 1800) -> dict:
    """Run :mod:`bench.child` with ``overrides``; returns its ``BENCH_CHILD`` dict."""
    proc = subprocess.run([sys.executable, "-m", "bench.child", *overrides], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout)
    for line in proc.stdout.splitlines():
        if line.startswith("BENCH_CHILD "):
            return json.loads(line[len("BENCH_CHILD "):])
    raise RuntimeError(f"bench.child failed (rc {proc.returncode}): {proc.stderr[-2000:]}")


def measure(sizes, work: Path, n_views: int, executor: str = "serial") -> dict:
    """One symbolic run on ``n_views`` views (0: all) in a fresh subprocess and fresh cache."""
    tag = f"{executor}_{n_views or 'all'}"
    overrides = ["method=symbolic", "scene=urban_canyon", views_override("urban_canyon", n_views),
                 f"render.spp={sizes.mem_spp}", f"observe.spp={sizes.mem_observe_spp}", "report=false",
                 f"cache.dir={work / 'cache' / tag}", f"hydra.run.dir={work / 'runs' / tag}",
                 f"executor={executor}", *sizes.extra]
    if executor == "dask":
        overrides += ["executor.n_workers=2", "executor.threads_per_worker=1"]
    out = run_child(overrides)
    res_path = work / "runs" / tag / "results.json"
    res = json.loads(res_path.read_text()) if res_path.is_file() else {}
    n = n_views if n_views > 0 else len(view_names("urban_canyon"))
    return {"views": n, "executor": executor, "rc": out["rc"], "wall_s": out["wall_s"],
            "maxrss_mib": out["maxrss_mib"], "tree_peak_mib": out["tree_peak_mib"],
            "timings_s": res.get("timings_s", {}), "error": None if out["rc"] == 0 else out["stderr_tail"]}


def run(sizes, work: Path, log=print) -> list[dict]:
    """All memory rows (serial at each ``sizes.mem_views``, then Dask if configured)."""
    rows = []
    plan = [(n, "serial") for n in sizes.mem_views]
    if sizes.mem_dask_views:
        plan.append((sizes.mem_dask_views, "dask"))
    for n, executor in plan:
        rows.append(measure(sizes, work, n, executor))
        r = rows[-1]
        log(f"[memory] {executor} {r['views']} view(s): rc {r['rc']}, {r['wall_s']:.1f} s, "
            f"peak RSS {r['maxrss_mib']:.0f} MiB, tree {r['tree_peak_mib']:.0f} MiB")
    return rows
