"""Section "megapixel": one 1920x1080 street view, the paper's pass against a plain render.

The default street view of urban_canyon (same pose, 65 degree horizontal field of view) at
1920x1080 pixels, ``sizes.mega_spp`` spp: the polynomial pass of ``method=symbolic_paper`` (tiles of
``method.memory_mb``) against Mitsuba ``path`` at max_depth N_max + 1, timed as section 1 does
(:func:`bench.render_ratio.measure_spp`, one warm-up, median of ``reps``), in a fresh
subprocess whose peak RSS is reported. The pass stores each tile's coefficients in the cache as
it renders them, as a run with a cache does, and the solve reads them back one tile at a time:
memory stays bounded by the tiles, not the image.

``python -m bench.megapixel <work folder> <spp> <reps>`` is that subprocess; it prints one line
``MEGAPIXEL {json}``.
"""
from __future__ import annotations

import json
import resource
import shutil
import subprocess
import sys
from pathlib import Path

from bench.common import ROOT
from bench.tables import f, table, yes
from bench.render_ratio import HOST_TARGET, RATIO_TARGET, _host

WIDTH, HEIGHT, VIEW = 1920, 1080, "street_002.png"


def variant(work: Path) -> Path:
    """urban_canyon with only its default view, at WIDTH x HEIGHT (same pose and field of view)."""
    from framework.scene import load_scene
    from framework.scene.write import pinhole_camera, write_colmap
    from scenes import BUNDLED_DIR
    from scenes.cameras import focal_from_fov
    from scenes.urban_canyon import FOV, landmarks
    folder = work / "urban_canyon_1080p"
    if (folder / "scene.yaml").is_file():
        return folder
    shutil.rmtree(folder, ignore_errors=True)
    shutil.copytree(BUNDLED_DIR / "urban_canyon", folder, ignore=shutil.ignore_patterns("sparse", "preview.png"))
    cam = load_scene(BUNDLED_DIR / "urban_canyon").camera(VIEW)
    big = pinhole_camera(VIEW, WIDTH, HEIGHT, focal_from_fov(WIDTH, FOV), cam.cam_from_world)
    write_colmap(folder / "sparse", [big], landmarks())
    return folder


def child(work: Path, spp: int, reps: int) -> dict:
    """Measure in this process (the subprocess of :func:`run`)."""
    from bench.render_ratio import build_problem, measure_spp
    from framework.config import compose
    folder = variant(work)
    cfg = compose(["method=symbolic_paper", f"scene.dir={folder}", f"views=[{VIEW}]", "observe.spp=16",
                   f"cache.dir={work / 'cache'}"])
    problem, method = build_problem(cfg)
    row = measure_spp(problem, method, spp, reps, cache_dir=work / "cache")   # tiles on disk, as a run stores them
    row.update(size=f"{WIDTH}x{HEIGHT}", memory_mb=method.options.memory_mb,
               maxrss_mib=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
    return row


def run(sizes, work: Path, log=print) -> dict:
    """The subprocess; its row (or the error)."""
    work.mkdir(parents=True, exist_ok=True)
    proc = subprocess.run([sys.executable, "-m", "bench.megapixel", str(work), str(sizes.mega_spp),
                           str(sizes.mega_reps), sizes.variant], cwd=ROOT, capture_output=True, text=True, timeout=3600)
    for line in proc.stdout.splitlines():
        if line.startswith("MEGAPIXEL "):
            row = json.loads(line[len("MEGAPIXEL "):])
            log(f"[megapixel] pass {row['pass_s']:.1f} s, render {row['render_s']:.1f} s, ratio {row['ratio']:.2f}, "
                f"peak {row['maxrss_mib']:.0f} MiB")
            return row
    return {"error": proc.stderr[-1500:], "rc": proc.returncode}


if __name__ == "__main__":
    from framework.render.backend import set_variant
    set_variant(sys.argv[4] if len(sys.argv) > 4 else "auto", channels=("R", "G", "B"))
    out = child(Path(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]))
    print("MEGAPIXEL " + json.dumps(out, default=float), flush=True)


# ----------------------------------------------------------------------------------------------
# BENCHMARKS.md
# ----------------------------------------------------------------------------------------------

def markdown(r: dict, *, target: float = RATIO_TARGET) -> list[str]:
    """Section 1b: the 1920x1080 view (:mod:`bench.megapixel`; ``target``: pass / render's)."""
    lines = ["## 1b. A megapixel view", ""]
    if "error" in r:
        return lines + [f"Failed: `{str(r['error'])[-300:]}`", ""]
    lines += [f"urban_canyon's default view at {r['size']} (same pose and field of view), {r['spp']} spp, "
              f"`method=symbolic_paper`, pass tiles of method.memory_mb = {r['memory_mb']:g} MiB, in a fresh "
              "subprocess; timed as section 1. As a run with a cache does, the pass writes each tile's "
              "per-pixel coefficients to the cache while the next tile renders (timed with it) and the "
              "solve's standard errors read them back one tile at a time: the peak is bounded by the "
              "tiles, not the image.", ""]
    body = [[r["size"], r["spp"], f(r["pass_s"], 1), f(r["render_s"], 1), f(r["ratio"], 2),
             yes(r["ratio"] <= target), _host(r), f(r["solve_s"], 2), r["n_monomials"], f(r["maxrss_mib"], 0)]]
    return lines + table(["view", "spp", "pass (s)", "render (s)", "pass / render", f"<= {target}",
                          f"host share (<= {HOST_TARGET:.0%})", "solve (s)", "monomials", "peak RSS (MiB)"], body) + [""]
