"""Section 3: method comparison at equal spp, in this process, via ``run_experiment``.

Observations are rendered once per (scene, views) into a shared observation cache and copied
into each run's fresh cache, so every run reads its observed images from that cache (they
are not part of its time) and computes everything else afresh.
"""
from __future__ import annotations

import json
import re
import shutil
import time
from pathlib import Path

from bench import baseline_cost
from bench.common import compose, resized_copy, seed_cache, views_override
from bench.render_ratio import build_problem
from framework.config import BUNDLED_SCENES
from framework.experiment import run_experiment
from bench.tables import f, table, yes
from bench.common import error_stats, observable_keys
from reports.convergence import equal_error_rows, error_curve

#: (label, method overrides, iterative-type: budget reduced on all views). The comparison is at the
#: paper's light model: ``symbolic`` is the paper's single truncated pass (``method=symbolic_paper``),
#: the baselines render max_depth N_max + 1 like it (``render.tail_bounces=0``); the default
#: symbolic method (tail and refinement) is a row of its own; ``lambertian_prior`` is the paper's
#: Table 1 fit (one truncated pass, the joint cost of eq. 6).
PAPER_LIGHT = ["render.tail_bounces=0"]
METHODS = [
    ("symbolic", ["method=symbolic_paper"], False),
    ("lambertian_prior", ["method=lambertian_prior", "method.tail_bounces=0", "method.refine=0", "method.cost=joint"],
     False),
    ("symbolic+init=lambertian_prior", ["method=symbolic_paper", "method.init=lambertian_prior"], False),
    ("iterative (noise fresh)", ["method=iterative", "method.noise=fresh", *PAPER_LIGHT], True),
    ("iterative (noise fixed)", ["method=iterative", "method.noise=fixed", *PAPER_LIGHT], True),
    ("differentiable", ["method=differentiable", *PAPER_LIGHT], True),
    # the same estimator on observations holding only N_max = 3 reflections (like the model):
    # separates the paper's truncation of longer paths from the estimator's own error
    ("symbolic (observations at N_max)", ["method=symbolic_paper", "observe.max_depth=4"], False),
    # the default: light beyond N_max at the guesses, passes repeated at the estimate until it settles
    ("symbolic (default: tail 4, refine)", ["method=symbolic"], False),
]


def _extra(sizes, method_overrides: list[str]) -> list[str]:
    """``sizes.extra`` restricted to what the method's config has (solver.* only for nlopt-solve ones)."""
    solve = any(o in ("method=symbolic", "method=symbolic_paper", "method=lambertian_prior") for o in method_overrides)
    return [o for o in sizes.extra if solve or not o.startswith("method.solver")]


def run_one(sizes, root: Path, label: str, scene: str, n_views: int, overrides: list[str], budget: int,
            log=print, resume: bool = False) -> dict:
    """One in-process run into ``root/<scene>/<views>/<label>``; returns a row dict with its results.

    ``resume``: a run folder that already holds a results.json (a run an interrupted benchmark
    finished) is read instead of run again; its ``wall_s`` is then the run's own total.
    """
    vtag = "single" if n_views == 1 else "all"
    run_dir, cache = _folders(root, label, scene, vtag)
    image = _image(sizes, n_views)
    row = {"label": label, "scene": scene, "views": vtag, "budget": budget, "run_dir": str(run_dir),
           "image": image}
    done = json.loads((run_dir / "results.json").read_text()) if resume and (run_dir / "results.json").is_file() else None
    if done is not None and done["settings"].get("budget_renders") == budget:
        log(f"[compare] {scene} {vtag} {label}: reused {run_dir}")
        return {**row, "n_views": len(done["settings"]["views"]), "wall_s": done["timings_s"]["total"], "results": done}
    for old in (run_dir, cache):            # an interrupted run's partial folder and its passes
        shutil.rmtree(old, ignore_errors=True)
    seed_cache(root / "cache" / "observed" / scene / vtag, cache)
    cfg = compose([*overrides, *_scene(sizes, root, scene, n_views), f"render.spp={sizes.cmp_spp}",
                   f"observe.spp={sizes.cmp_observe_spp}", f"budget.renders={budget}", "report=false",
                   f"cache.dir={cache}", *_extra(sizes, overrides)])
    t = time.perf_counter()
    res = run_experiment(cfg, run_dir)
    wall = time.perf_counter() - t
    log(f"[compare] {scene} {vtag} {label}: {res['timings_s']['total']:.1f} s, {res['renders']} renders")
    return {**row, "n_views": len(res["settings"]["views"]), "wall_s": wall, "results": res}


def _folders(root: Path, label: str, scene: str, vtag: str) -> tuple[Path, Path]:
    """The run folder and the pass cache of the run ``label``."""
    slug = re.sub(r"[^A-Za-z0-9_.-]+", "_", label.replace("=", "-")).strip("_")
    return root / scene / vtag / slug, root / "cache" / scene / vtag / slug


#: renders of each method's warm-up run (:func:`warm_kernels`): the default symbolic run's first
#: pass and its three refinement passes (with fewer it stops before its first solve)
WARM_BUDGET = 4


def warm_kernels(sizes, root: Path, scene: str, n_views: int, log=print) -> float:
    """One run of every method of :data:`METHODS` at :data:`WARM_BUDGET` renders, not recorded, so
    that the timed runs find their Dr.Jit kernels compiled whatever the machine ran before. On a
    fresh machine (Dr.Jit's kernel cache empty, 2026-12-06) the timed runs without it compiled
    0.18-0.92 s each (the symbolic run 0.18 of its 0.53 s). With it, and since a later run of a
    process compiles nothing (docs/design-notes.md, "Kernels a later run would compile again"),
    every timed run but the differentiable one compiled 0 s (0.02 s) at f2e5fea.
    The warm-up runs' folders are removed; a warm-up that fails is logged
    and the timed run meets the failure itself. Seconds spent."""
    t = time.perf_counter()
    vtag = "single" if n_views == 1 else "all"
    for label, overrides, _ in METHODS:
        try:
            run_one(sizes, root, f"warm-up {label}", scene, n_views, overrides, WARM_BUDGET, log=log)
        except Exception as exc:  # noqa: BLE001 - the timed run reports it
            log(f"[compare] warm-up of {label} failed: {exc!r}"[:300])
        for folder in _folders(root, f"warm-up {label}", scene, vtag):
            shutil.rmtree(folder, ignore_errors=True)
    return time.perf_counter() - t


def _image(sizes, n_views: int) -> int | None:
    """Image width of the runs on ``n_views`` views (None: the scene's own)."""
    return sizes.cmp_single_image if n_views == 1 else sizes.cmp_all_image


def _scene(sizes, root: Path, scene: str, n_views: int) -> list[str]:
    """The scene and views overrides (the default view, or all views) on a copy of the scene at
    ``cmp_single_image`` / ``cmp_all_image`` pixels wide when that is set (written once under
    ``root/scenes``)."""
    image = _image(sizes, n_views)
    n = 1 if n_views == 1 else sizes.all_views
    if image is None:
        return [f"scene={scene}", "views=default" if n_views == 1 else views_override(scene, n)]
    folder = root / "scenes" / f"{scene}_{image}"
    if not (folder / "scene.yaml").is_file():
        resized_copy(BUNDLED_SCENES / scene, folder, image)
    return [f"scene={scene}", f"scene.dir={folder}", views_override(scene, n, folder)]


def warm_observations(sizes, root: Path, scene: str, n_views: int) -> float:
    """Render the observations of ``scene`` once into the shared observation cache; seconds spent."""
    vtag = "single" if n_views == 1 else "all"
    cfg = compose([*_scene(sizes, root, scene, n_views), f"observe.spp={sizes.cmp_observe_spp}",
                   f"cache.dir={root / 'cache' / 'observed' / scene / vtag}"])
    t = time.perf_counter()
    build_problem(cfg)                         # renders the observations into the cache
    return time.perf_counter() - t


def path_render(sizes, root: Path, log=print) -> dict:
    """A plain ``path`` render of the single view timed in this process, as the iterative
    baseline's runs render it (:func:`bench.baseline_cost.measure`)."""
    overrides = next(o for label, o, _ in METHODS if label == "iterative (noise fresh)")
    cfg = compose([*overrides, *_scene(sizes, root, "urban_canyon", 1), f"render.spp={sizes.cmp_spp}",
                   f"observe.spp={sizes.cmp_observe_spp}", f"cache.dir={root / 'cache' / 'observed' / 'urban_canyon' / 'single'}",
                   *_extra(sizes, overrides)])
    out = baseline_cost.measure(cfg, reps=max(3, sizes.ratio_reps))
    log(f"[compare] path render of {out['view']} at {out['spp']} spp: {out['path_s']:.4f} s")
    return out


#: runs that raised: ``(scene, views, label, repr of the exception)``, listed in BENCHMARKS.md
FAILED: list[tuple] = []


def try_one(*args, log=print, resume: bool = False) -> dict | None:
    """:func:`run_one`, or None (recorded in :data:`FAILED`) if the run raises."""
    try:
        return run_one(*args, log=log, resume=resume)
    except Exception as exc:  # one broken method must not lose the other measurements
        FAILED.append((args[3], "single" if args[4] == 1 else "all", args[2], repr(exc)[:300]))
        log(f"[compare] FAILED {FAILED[-1]}")
        return None


def lr_sweep(sizes, root: Path, log=print, resume: bool = False) -> list[dict]:
    """The differentiable baseline at the learning rates ``sizes.cmp_lr_sweep`` (the default, in
    its options, is the comparison's own run), single view, the comparison's budget."""
    rows = [try_one(sizes, root, f"differentiable lr={lr}", "urban_canyon", 1,
                    ["method=differentiable", f"method.lr={lr}", *PAPER_LIGHT], sizes.cmp_budget, log=log,
                    resume=resume) for lr in sizes.cmp_lr_sweep]
    return [r for r in rows if r is not None]


def run(sizes, root: Path, log=print, resume: bool = False) -> list[dict]:
    """All comparison runs on urban_canyon: single view then all views (failed runs left out)."""
    rows = []
    for n_views in (1, 0):
        warm_observations(sizes, root, "urban_canyon", n_views)
        warm_kernels(sizes, root, "urban_canyon", n_views, log=log)
        for label, overrides, reduced in METHODS:
            budget = sizes.cmp_budget_all if (reduced and n_views != 1) else sizes.cmp_budget
            if label == "differentiable" and n_views != 1:
                budget = sizes.cmp_budget_all_differentiable
            rows.append(try_one(sizes, root, label, "urban_canyon", n_views, overrides, budget, log=log,
                                resume=resume))
    return [r for r in rows if r is not None]


# ----------------------------------------------------------------------------------------------
# BENCHMARKS.md
# ----------------------------------------------------------------------------------------------

SPEEDUP_TARGET = {"iterative (noise fresh)": 100, "iterative (noise fixed)": 100, "differentiable": 20}


def markdown(rows: list[dict], sizes, report_path, *, path: dict | None = None) -> list[str]:
    """Section 3's text; ``path``: the plain render timed beside the runs (:func:`path_render`)."""
    lines = ["## 3. Method comparison at equal spp", "",
             f"urban_canyon, render.spp = {sizes.cmp_spp}, observe.spp = {sizes.cmp_observe_spp}, "
             f"budget.renders = {sizes.cmp_budget}"
             + (f" on one view; on all views {sizes.cmp_budget_all} for the iterative baselines and "
                f"{getattr(sizes, 'cmp_budget_all_differentiable', sizes.cmp_budget_all)} for the differentiable "
                "one (the floors below say whether each curve had levelled off within its budget)")
             + _sizes_line(sizes)
             + ". Every run is in this process, by "
             "`run_experiment`, after a warm-up run of every method at "
             f"{WARM_BUDGET} renders (not recorded), so that the timed runs find their kernels "
             "compiled whatever the machine ran before; each run's compilation stays apart in its "
             "results.json (`timings_s.compile`) and is part of its total. Observations come from a shared observation cache (rendered once per "
             "view set, copied into each run's otherwise empty cache), so totals exclude them. Errors: "
             "over the parameters and channels the symbolic run on the same views reports observable. "
             "Times are wall-clock seconds on a machine that may have been shared (other sections or tests "
             "may run beside it): renders are the load-free measure of cost. "
             + (baseline_cost.device_line(rows) if rows else ""),
             "The comparison report of the run folders (`python -m reports`) is written to the bench's "
             "run folder (`--runs`), which is not committed.", ""]
    for vtag in ("single", "all"):
        sub = [r for r in rows if r["views"] == vtag]
        if not sub:
            continue
        base = next(r for r in sub if r["label"] == "symbolic")
        keys = observable_keys(base["results"])
        image = sub[0].get("image")
        lines += [f"### {'Single view (default)' if vtag == 'single' else 'All views'}"
                  + (f" ({image} pixels wide)" if image else ""), ""]
        lines += summary_table(sub)
        lines += [""] + _speedup_verdicts(sub, keys) + [""] + _equal_error(sub, keys)
        lines += baseline_cost.markdown(sub, path)
    for scene, vtag, label, err in FAILED:
        lines.append(f"- FAILED: {scene} {vtag} {label}: `{err}` (no numbers)")
    return lines + ([""] if FAILED else [])


def _sizes_line(sizes) -> str:
    """What the section's image sizes cut, and why."""
    single, every = getattr(sizes, "cmp_single_image", None), getattr(sizes, "cmp_all_image", None)
    if single is None and every is None:
        return ""
    where = " and ".join(x for x in (f"the single view at {single}" if single else "",
                                     f"all views at {every}" if every else "") if x)
    return (f"; {where} pixels wide (the cameras scaled, the observations rendered at that size, street_002 "
            "is 200 wide in the bundled scene): a baseline's run is hundreds of renders, which at the "
            "scene's own size do not fit in the hour the whole benchmark has on a 2-core machine. Every method runs at the same size, so the ratios and the equal-error "
            "times compare like with like; the errors are those of the smaller images (fewer pixels per "
            "weight), not the bundled view's")


def summary_table(rows: list[dict]) -> list[str]:
    """The comparison's table of one view set: each method's time, renders and errors against the
    symbolic pass's (README.md shows the single-view one)."""
    base = next(r for r in rows if r["label"] == "symbolic")
    keys = observable_keys(base["results"])
    return table(["method", "views", "budget", "total (s)", "renders", "worst abs. error", "mean abs. error",
                  "time / symbolic"], [_cmp_row(r, base if r is not base else None, keys) for r in rows])


def _cmp_row(row: dict, base: dict | None, keys: set) -> list:
    res = row["results"]
    worst, mean = error_stats(res, keys)
    total = res["timings_s"]["total"]
    ratio = total / base["results"]["timings_s"]["total"] if base else None
    label = row["label"] + (" (passes read from a cache: time not comparable)" if res.get("views_from_cache") else "")
    return [label, row["n_views"], row["budget"], f(total, 1), res["renders"], f(worst), f(mean),
            f(ratio, 1) if ratio else "1"]


def _speedup_verdicts(rows: list[dict], keys: set) -> list[str]:
    base = next(r for r in rows if r["label"] == "symbolic")
    b_worst, b_mean = error_stats(base["results"], keys)
    out = []
    for r in rows:
        if r["label"] not in SPEEDUP_TARGET:
            continue
        ratio = r["results"]["timings_s"]["total"] / base["results"]["timings_s"]["total"]
        worst, mean = error_stats(r["results"], keys)
        err_ok = b_worst <= worst
        target = SPEEDUP_TARGET[r["label"]]
        out.append(f"- {r['label']} / symbolic total time = {ratio:.1f} (target >= {target}: "
                   f"{yes(ratio >= target)}); symbolic worst |error| {f(b_worst)} vs {f(worst)} "
                   f"({'equal or lower' if err_ok else 'higher'}); target at equal or lower error: "
                   f"{yes(ratio >= target and err_ok)}.")
    return out


def _equal_error(rows: list[dict], keys: set) -> list[str]:
    """Per baseline: the time (and renders) its iterates need to reach the symbolic run's final
    worst error, and the error it levels off at, from the results' ``trace``."""
    curves = {r["label"]: [c] for r in rows if (c := error_curve(r["results"], keys)) is not None}
    out = []
    for row in equal_error_rows(curves, "symbolic"):
        if row["method"] not in SPEEDUP_TARGET:
            continue
        reach = (f"{f(row['time_s'], 1)} s ({row['renders']} renders), {f(row['ratio'], 1)} x symbolic"
                 if row["time_s"] is not None else
                 f"not reached in {row['max_renders']} renders / {f(row['max_time_s'], 1)} s")
        drop = row["drop_per_tenth"]
        floor = f"{f(row['floor'])} " + ("(flat)" if row["flattened"] else "(too few iterates to tell)"
                                         if drop != drop else f"(still falling {100 * drop:.0f} % per tenth)")
        out.append([row["method"], f(row["target"]), reach, floor])
    if not out:
        return []
    return (["At equal error (from each run's iterates, results.json `trace`): the time a baseline needs "
             "to reach the symbolic run's final worst |error|, and its floor: the median worst |error| over "
             "the last 10 % of its iterates, *flat* when a least-squares line through log(worst |error|) "
             "over the last 30 % of them falls by less than 10 % per tenth of the iterates (the curve "
             "has levelled off within the budget; otherwise the drop per tenth is given).", ""]
            + table(["method", "symbolic worst |error|", "time to reach it", "floor"], out) + [""])


def lr_sweep_markdown(rows: list[dict], sweep: list[dict]) -> list[str]:
    """The differentiable baseline's learning rates on the single view (the default is the
    comparison's run): errors over the symbolic run's observable parameters."""
    single = [r for r in rows if r["views"] == "single"]
    base = next((r for r in single if r["label"] == "symbolic"), None)
    default = next((r for r in single if r["label"] == "differentiable"), None)
    if base is None or default is None:
        return []
    if not sweep:
        return ["### Learning rate of the differentiable baseline (single view)", "",
                "Not run at these sizes (`Sizes.cmp_lr_sweep` is empty: two more baseline runs of the "
                "comparison's budget, cut for the benchmark's hour). Give it rates, e.g. (0.05, 0.2), to "
                "sweep Adam's learning rate around the shipped default.", ""]
    keys = observable_keys(base["results"])
    runs = [(r["results"]["settings"]["method_settings"]["lr"], r) for r in sweep + [default]]
    def floor(r):
        c = error_curve(r["results"], keys)
        return "-" if c is None else f"{f(c.floor)}{' (flat)' if c.flattened else ''}"
    out = [[f"{lr}{' (default)' if r is default else ''}", r["results"]["renders"],
            *(f(x) for x in error_stats(r["results"], keys)), floor(r), f(r["results"]["image_rmse"], 4),
            f(r["results"]["timings_s"]["total"], 1)] for lr, r in sorted(runs, key=lambda t: t[0])]
    return (["### Learning rate of the differentiable baseline (single view)", "",
             "Adam's learning rate swept at the comparison's budget; the shipped default is marked. "
             "Errors at the end and the floor as above (a constant rate ends in a noise ball of radius "
             "about the rate: smaller rates end lower but need more renders).", ""]
            + table(["lr", "renders", "worst abs. error", "mean abs. error", "floor", "image RMSE", "total (s)"],
                    out) + [""])
