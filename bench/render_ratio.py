"""Section 1: one polynomial (symbolic) pass vs a plain Mitsuba ``path`` render of the same view.

Both at the same spp on the same 200x200 view; ``path`` with ``max_depth = N_max + T + 1`` and
the box filter (as the pass): the paper's pass (``method=symbolic_paper``, T = 0) at every spp,
and the default pass (``method=symbolic``, T = 4) at one. The pass is timed as the method runs it
(:func:`methods.symbolic.system.polynomial_pass.render_view_task`: coefficients, Gram accumulation,
sparse coefficients), and the solve (:func:`methods.symbolic.loop.refinement.solve_system`: the solver and
the uncertainty)
on its Gram system; each the median of ``reps`` runs after a warm-up (the solve's stages and
evaluation count: of the last run).
"""
from __future__ import annotations

import dataclasses
import statistics
import time
from pathlib import Path

from framework.config import compose
from framework.experiment import prepare
from framework.render.jit_timing import kernel_split
from framework.render.mitsuba_scene import MitsubaScene, max_depth_for
from methods._common import initial_guess, segment_groups
from methods.symbolic.loop.refinement import solve_system
from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.polynomial_pass import render_view_task, tile_pixels_for, view_task
from bench.tables import f, table, yes


def build_problem(cfg):
    """``(problem, method)`` as :func:`framework.experiment.run_experiment` builds them."""
    problem, method, _ = prepare(cfg)
    return problem, method


def _timed(fn, reps: int) -> tuple[float, object]:
    """Median seconds of ``reps`` calls of ``fn`` after one warm-up call, and the last output."""
    out = fn()
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def _host_share(fn) -> float:
    """The share of one call of ``fn``'s wall time outside Dr.Jit's kernels (kernel history)."""
    wall, kernels, _ = kernel_split(fn)
    return max(0.0, wall - kernels) / wall


def _pass_fn(problem, method, spp: int, cache_dir=None):
    """A no-argument function running the method's polynomial pass of view 0 at ``spp``; with
    ``cache_dir`` its tiles are stored there as they are rendered (as a run with a cache does),
    so that its coefficients are never all in memory."""
    params = problem.parameters
    x0, _ = initial_guess(method.options, problem)
    N, T = problem.settings.max_bounces, problem.settings.tail_bounces
    tile = tile_pixels_for(method.options.memory_mb, spp, N, problem.n_channels, T)
    key = {"bench": "pass", "scene": problem.scene.content_hash, "view": problem.cameras[0].name, "spp": spp,
           "tile_pixels": tile, "tail_bounces": T}
    task = view_task(problem, params, x0, N, 0, spp=spp, seed=int(problem.seed), prob_floor=method.options.prob_floor,
                     tile_pixels=tile, cross_gram=method.options.gram == "cross", tail_bounces=T, cache_dir=cache_dir,
                     key=key)
    variant = problem.settings.variant
    calls = iter(range(1 << 30))

    def run():
        # each call stores into its own folder, as a run writes new entries (replacing a file that
        # exists made the filesystem flush it first: 1.4 s of the 1920x1080 pass)
        if cache_dir is None:
            return render_view_task(task, variant=variant)
        return render_view_task(dataclasses.replace(task, cache_dir=str(Path(cache_dir) / f"call{next(calls)}")),
                                variant=variant)
    return run, x0


def _render_fn(problem, spp: int, rho):
    """A no-argument function rendering view 0 with ``path`` (max_depth N_max + 1, box filter)
    at the weights ``rho`` (the pass's guesses: a render of the iterative method's loop)."""
    depth = max_depth_for(problem.settings.max_bounces + problem.settings.tail_bounces)
    ms = MitsubaScene(problem.scene, problem.cameras[:1], spp=spp, integrator={"type": "path", "max_depth": depth})
    ms.set_weights(rho, problem.parameters)    # weights start at 0: a black scene renders too fast
    return lambda: ms.render(0, spp=spp, seed=2)


def measure_spp(problem, method, spp: int, reps: int, cache_dir=None) -> dict:
    """Pass, render and solve times at one spp; returns a row dict. ``cache_dir``: the pass
    stores its tiles there (:func:`_pass_fn`)."""
    pass_fn, x0 = _pass_fn(problem, method, spp, cache_dir)
    t_pass, (system, coefficients) = _timed(pass_fn, reps)
    host = _host_share(pass_fn)
    basis = MonomialBasis(len(problem.parameters), problem.settings.max_bounces, system.codes)
    t_render, _ = _timed(_render_fn(problem, spp, x0), reps)
    # the default std (sandwich) reads the view's per-pixel coefficients: time it with them
    view0 = dataclasses.replace(problem, cameras=problem.cameras[:1])      # the pass covers view 0
    views = lambda: [(coefficients, view0.observed[view0.cameras[0].name], None)]
    t_solve, fit = _timed(lambda: solve_system(system, basis, view0.parameters, x0, view0, method.options,
                                               views=views, groups=segment_groups(view0.parameters)), reps)
    return {"spp": spp, "pass_s": t_pass, "render_s": t_render, "ratio": t_pass / t_render, "host_share": host,
            "solve_s": t_solve, "solve_share": t_solve / t_render, "solve_share_pass": t_solve / t_pass,
            "solve_stages_s": fit.stages_s, "solver_evaluations": fit.solve.n_evals,
            "n_monomials": basis.size, "n_params": len(problem.parameters)}


def run(sizes, cache_dir, log=print) -> dict:
    """Section 1 on urban_canyon's default view; returns ``{"rows": [...], "view": ..., ...}``."""
    base = ["scene=urban_canyon", f"observe.spp={sizes.cmp_observe_spp}", f"cache.dir={cache_dir}", *sizes.extra]
    cfg = compose(["method=symbolic_paper", *base])          # the paper's pass: N_max, no tail
    problem, method = build_problem(cfg)
    rows = []
    for spp in sizes.ratio_spps:
        rows.append(measure_spp(problem, method, spp, sizes.ratio_reps) | {"tail": 0})
        log(f"[ratio] spp {spp}: pass {rows[-1]['pass_s']:.2f} s, render {rows[-1]['render_s']:.3f} s, "
            f"ratio {rows[-1]['ratio']:.1f}")
    # the default symbolic pass (tail T beyond N_max) against path at max_depth N_max + T + 1
    default, method_default = build_problem(compose(["method=symbolic", *base]))
    spp = sizes.ratio_spps[min(1, len(sizes.ratio_spps) - 1)]
    rows.append(measure_spp(default, method_default, spp, sizes.ratio_reps) | {"tail": default.settings.tail_bounces})
    log(f"[ratio] default (tail {rows[-1]['tail']}) spp {spp}: ratio {rows[-1]['ratio']:.1f}")
    cam = problem.cameras[0]
    return {"rows": rows, "view": cam.name, "size": f"{cam.width}x{cam.height}",
            "max_bounces": int(cfg.render.max_bounces), "reps": sizes.ratio_reps,
            "segments": len(problem.scene.segments), "kernels": sorted({p.kernel for p in problem.parameters}),
            "channels": list(problem.scene.channels), "observe_spp": sizes.cmp_observe_spp}


# ----------------------------------------------------------------------------------------------
# BENCHMARKS.md
# ----------------------------------------------------------------------------------------------

RATIO_TARGET, SOLVE_TARGET, HOST_TARGET = 1.3, 0.05, 0.10
#: pass / render on a GPU, where the device's kernels are short and the host's part weighs more
GPU_RATIO_TARGET = 1.5


def markdown(r: dict, *, target: float = RATIO_TARGET) -> list[str]:
    """Section 1 (``target``: pass / render's, :data:`GPU_RATIO_TARGET` for a GPU's run)."""
    n_e, d = r["rows"][0]["n_monomials"], r["rows"][0]["n_params"]
    lines = ["## 1. Symbolic pass vs plain render", "",
             f"urban_canyon, view {r['view']} ({r['size']}), {r['segments']} segments x "
             f"{len(r['kernels'])} kernels (D = {d}), N_max = {r['max_bounces']}, N_e = {n_e}, "
             f"channels {','.join(r['channels'])}. Pass = the method's per-view pass (coefficients, Gram "
             f"accumulation, sparse coefficients) of `method=symbolic_paper` (T = 0); render = Mitsuba `path`, "
             f"max_depth = N_max + T + 1, box filter, same view and spp; the last row is the default "
             f"`method=symbolic` pass with its tail of T reflections beyond N_max. Median of {r['reps']} after one warm-up. N_e = the monomials that "
             f"occur (of C(D + N_max, N_max)). Solve = the method's solve on that pass's sparse Gram system "
             f"(PSD projection, solver multi-start, sandwich uncertainty from the per-pixel coefficients), median "
             f"the same way; its stages (PSD projection, the solver with its evaluation count) are those of "
             f"the last run. Host share = the pass's wall time outside Dr.Jit's kernels (wall minus the "
             f"kernels' execution time in Dr.Jit's kernel history), one run after the median's.", ""]
    rows = [[f"{x['spp']}" + (f" (default, T = {x['tail']})" if x.get("tail") else ""), f(x["pass_s"], 2), f(x["render_s"], 3), f(x["ratio"], 2),
             yes(x["ratio"] <= target), _host(x), f(x["solve_s"], 3), _stages(x), f"{100 * x['solve_share']:.1f} %",
             f"{100 * x['solve_share_pass']:.1f} %", yes(x["solve_share"] <= SOLVE_TARGET)] for x in r["rows"]]
    return lines + table(["spp", "pass (s)", "render (s)", "pass / render", f"<= {target}",
                          f"host share (<= {HOST_TARGET:.0%} at 256 spp)", "solve (s)", "of which PSD / solver (evals)", "solve / render", "solve / pass",
                          f"solve/render <= {SOLVE_TARGET:.0%}"], rows) + [""]


def _host(row: dict) -> str:
    """The pass's wall time outside Dr.Jit's kernels, as a share (n/a in sections measured before
    the bench recorded it)."""
    return "n/a" if row.get("host_share") is None else f"{100 * row['host_share']:.0f} %"


def _stages(row: dict) -> str:
    st = row.get("solve_stages_s")
    if not st:
        return "n/a"
    return f"{st.get('psd', 0):.3f} / {st.get('solver', st.get('nlopt', 0)):.3f} ({row.get('solver_evaluations', '?')})"
