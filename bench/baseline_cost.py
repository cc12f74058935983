"""Section 3's cost of one baseline render against a plain Mitsuba ``path`` render.

The iterative baseline renders the scene again at every evaluation; its per-render cost should be
a plain render's (target: within :data:`PER_RENDER_TARGET`), with its kernels compiled once, not
per set of weights. The plain render is timed in the comparison's process, on the same view at the
same spp and ``max_depth`` and at the method's initial weights; the baselines' own seconds come
from their results.json (``timings_s.render`` over ``renders``, compilation included, and
``timings_s.compile`` apart).
"""
from __future__ import annotations

import statistics
import time

from bench.render_ratio import build_problem
from bench.tables import f, table, yes
from framework.render.mitsuba_scene import MitsubaScene
from methods import _common as C
from reports.data import device_of

#: per render, iterative baseline / plain ``path`` render
PER_RENDER_TARGET = 1.2


def measure(cfg, *, reps: int) -> dict:
    """Median seconds of ``reps`` ``path`` renders (after one warm-up, each with a fresh seed) of
    view 0 of the run ``cfg`` composes, at its ``render.spp`` and the baselines' ``max_depth``."""
    problem, method = build_problem(cfg)
    spp = problem.settings.spp
    ms = MitsubaScene(problem.scene, problem.cameras[:1], spp=spp,
                      integrator={"type": "path", "max_depth": C.max_depth(problem)})
    rho, _ = C.initial_guess(method.options, problem)
    ms.set_weights(rho, problem.parameters)         # weights start at 0: a black scene renders too fast
    ms.render(0, spp=spp, seed=1)
    times = []
    for seed in range(reps):
        t = time.perf_counter()
        ms.render(0, spp=spp, seed=2 * seed + 3)
        times.append(time.perf_counter() - t)
    return {"path_s": statistics.median(times), "reps": reps, "spp": spp, "view": problem.cameras[0].name,
            "max_depth": C.max_depth(problem)}


def markdown(rows: list[dict], path: dict | None) -> list[str]:
    """The per-render table of the single-view baselines against ``path`` (nothing without it)."""
    baselines = [r for r in rows if r["views"] == "single" and r["label"].startswith(("iterative", "differentiable"))]
    if not path or not baselines:
        return []
    out = [_row(r, path["path_s"]) for r in baselines]
    return ([f"Per render, on view {path['view']} at {path['spp']} spp (max_depth {path['max_depth']}): a "
             f"plain `path` render in the same process took {f(path['path_s'], 4)} s (median of "
             f"{path['reps']} after a warm-up). A baseline's render is `timings_s.render` over its renders, "
             "its kernel compilation included (also given apart, `timings_s.compile`, whole run); a "
             "differentiable render is a forward or a backward pass (`prb_dirac`), shown for its cost only.", ""]
            + table(["method", "renders", "render (s)", "compile (s)", "per render (s)", "/ path",
                     f"<= {PER_RENDER_TARGET}"], out) + [""])


def _row(row: dict, path_s: float) -> list:
    res = row["results"]
    timings, renders = res["timings_s"], res["renders"]
    per = timings["render"] / renders if renders else float("nan")
    ratio = per / path_s
    verdict = yes(ratio <= PER_RENDER_TARGET) if row["label"].startswith("iterative") else "-"
    return [row["label"], renders, f(timings["render"], 1), f(timings.get("compile"), 2), f(per, 4),
            f(ratio, 2), verdict]


def device_line(rows: list[dict]) -> str:
    """Where the section's runs rendered (results.json ``settings.variant`` and ``.device``)."""
    places = sorted({device_of(r["results"]) for r in rows})
    return f"Rendered with {'; '.join(places)}: every time and ratio below is measured there."
