"""One inversion run: load the scene, get the observations, run the method, write the run folder.

:func:`run_experiment` is what ``python -m framework.run`` calls inside Hydra; tests call it
directly with a composed config. Input checks come first; the run folder gets results.json
only when everything else succeeded.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path
from typing import Callable

from omegaconf import DictConfig, OmegaConf

from framework.cache import Cache
from framework.config import RunSettings, requested_views, scene_dir
from framework.errors import ConfigError
from framework.holdout import HeldOut, check_held_out, fitted_light, held_out_scenes, holdout_names, split_holdout
from framework.holdout_run import holdout_entries
from framework.brdf_kernels import canonical
from framework.observe import observed_images
from framework.registry import Method, Problem, get_method, refuse_survey_unknowns
from framework.render import backend
from framework.render.jit_timing import CompileTimer
from framework.render.mitsuba_scene import segment_maps as view_segment_maps
from framework.results import (check_output_names, results_dict, write_relit_images, write_results,
                               write_view_images)
from framework.scene import load_scene

log = logging.getLogger(__name__)


#: Most samples Mitsuba traces in one render of a view: its sample indices are 32-bit.
SAMPLES_PER_VIEW_MAX = 2**32 - 1


def select_cameras(scene, cfg: DictConfig) -> list:
    """The cameras of the views the configuration selects; ``views=all``: every view lit by
    scene.yaml's ``emitters`` (the views of its ``lights`` are selected by name)."""
    names = requested_views(cfg)
    return scene.lit_by(None) if names is None else [scene.camera(n) for n in names]


def check_config(cfg: DictConfig) -> RunSettings:
    """Every check of a composed configuration that needs no scene, before anything is loaded
    or written; the command line runs it before Hydra creates the run folder.

    Returns the checked settings (variant not resolved yet); ConfigError names the first bad key.
    Writes nothing: whether the cache folder can be written is :meth:`Cache.check_writable`'s.
    """
    settings = RunSettings.from_config(cfg)
    get_method(str(cfg.method.name)).options_from(cfg.method)
    requested_views(cfg)
    holdout_names(cfg)
    cache, root = Cache(settings.cache_dir), scene_dir(cfg).resolve()
    if cache.dir is not None and cache.dir.is_relative_to(root):
        raise ConfigError(f"cache.dir={cache.dir} is inside the scene folder {root}, "
                          "which runs never write to: choose a cache.dir outside it")
    return settings


def _check_samples(scene, cameras, settings: RunSettings) -> None:
    """spp x pixels of the largest selected view within what one Mitsuba render can trace
    (``observe.spp`` only when the observations are rendered)."""
    view = max(cameras, key=lambda c: c.width * c.height)
    pixels = view.width * view.height
    spps = {"render.spp": settings.spp} | ({"observe.spp": settings.observe.spp} if scene.images is None else {})
    for key, spp in spps.items():
        if spp * pixels > SAMPLES_PER_VIEW_MAX:
            raise ConfigError(f"{key}={spp} is too large for view {view.name} ({view.width}x{view.height} "
                              f"pixels): Mitsuba renders at most 2**32 - 1 samples per view, so use "
                              f"{key} <= {SAMPLES_PER_VIEW_MAX // pixels}")


def _check_kernels_present(scene, kernels: tuple[str, ...] | None) -> None:
    """``method.kernels`` selects at least one weight of the scene (else the method has nothing
    to estimate and fails deep in the solve), and every kernel it lists is on some segment (a
    kernel listed but absent, ``glossy(0.3)`` for the scene's ``glossy(0.2)``, would otherwise be
    dropped without a word and its light go into the other kernels)."""
    if kernels is None:
        return
    present = sorted({canonical(k) for s in scene.segments for k in s.kernels})
    if not scene.parameters(kernels=kernels):
        raise ConfigError(f"method.kernels={list(kernels)} selects no weight of scene {scene.name}, whose "
                          f"kernels are {', '.join(present)}: list at least one of them")
    absent = [k for k in kernels if k not in present]
    if absent:
        raise ConfigError(f"method.kernels lists {', '.join(absent)}, which no segment of scene {scene.name} "
                          f"has (its kernels: {', '.join(present)}): list only the scene's kernels, or use all")


def _usable_cameras(scene, cameras) -> tuple[list, dict[str, str]]:
    """The selected views that constrain some parameter, and why each other one is left out.

    One rule for synthetic observations and photographs
    (:func:`framework.render.checks.check_lit_and_seen`): a view with no usable pixel, whose
    usable pixels see only sky, or whose segments no light reaches is left out with a warning
    (results.json ``views_left_out``); a run where that is every view is a SceneError.
    """
    from framework.render.checks import check_views, view_problems
    weights = None if scene.weights is None else {c.name: scene.weights[c.name] for c in cameras}
    found = check_views(scene, cameras, weights=weights)
    left_out = view_problems(found, weights)
    return [c for c in cameras if c.name not in left_out], left_out


def prepare(cfg: DictConfig, run_dir: str | Path | None = None) -> tuple[Problem, Method, float]:
    """The problem and the method of a composed configuration, and the seconds spent rendering
    observations (0 when cached): the settings checked, the scene loaded, the variant set, the
    views selected (those that constrain no parameter left out, :func:`_usable_cameras`), the
    names of the files the run will write into ``run_dir`` checked
    (:func:`framework.results.check_output_names`), the observations read or rendered.
    ConfigError/SceneError on bad input."""
    settings = check_config(cfg)
    Cache(settings.cache_dir).check_writable()     # before anything is loaded
    method = get_method(str(cfg.method.name))(cfg.method)
    backend.use_backend(str(cfg.variant))      # what loading evaluates (a sunsky) runs on the run's device
    loaded = load_scene(scene_dir(cfg))
    cameras, held = split_holdout(loaded, select_cameras(loaded, cfg), holdout_names(cfg))
    scene = loaded.under(fitted_light(loaded, cameras))          # the fit sees its views' light alone
    refuse_survey_unknowns(scene, type(method))
    relit = held_out_scenes(loaded, scene, held)
    settings = dataclasses.replace(settings, variant=backend.set_variant(str(cfg.variant), channels=scene.channels))
    _check_samples(scene, cameras + held, settings)
    _check_kernels_present(scene, getattr(method.options, "kernels", None))
    if run_dir is not None:
        check_output_names(run_dir, [c.name for c in cameras + held])
    check_held_out(scene, held, relit)
    cameras, left_out = _usable_cameras(scene, cameras)
    observed, t_observe = _observations(scene, cameras, held, relit, settings)
    weights = None if scene.weights is None else {c.name: scene.weights[c.name] for c in cameras}
    held_out = HeldOut(held, {c.name: observed.pop(c.name) for c in held},
                       None if scene.weights is None else {c.name: scene.weights[c.name] for c in held}, relit)
    problem = Problem(scene=scene, cameras=cameras, observed=observed, parameters=scene.parameters(),
                      settings=settings, weights=weights, views_left_out=left_out, held_out=held_out)
    method.check_problem(problem)        # what the method cannot do with this scene: before any run folder
    return problem, method, t_observe


def _observations(scene, cameras: list, held: list, relit: dict, settings: RunSettings) -> tuple[dict, float]:
    """The observed images of the fitted and the held-out views, and the seconds spent rendering
    them: each view's under its own light (``relit``: the held-out views of another light)."""
    cache = Cache(settings.cache_dir)
    own = [c for c in held if c.name not in relit]
    observed, seconds = observed_images(scene, cameras + own, settings, cache=cache, check=False)
    for light in dict.fromkeys(relit[c.name].light for c in held if c.name in relit):
        views = [c for c in held if c.name in relit and relit[c.name].light == light]
        more, t = observed_images(relit[views[0].name], views, settings, cache=cache, check=False)
        observed, seconds = {**observed, **more}, seconds + t
    return observed, seconds


def run_experiment(cfg: DictConfig, run_dir: str | Path, *,
                   write_report: Callable[[Path, dict], object] | None = None) -> dict:
    """Run ``cfg.method`` on ``cfg.scene``; write the run folder; return the results dict.

    ``write_report(run_dir, results)`` writes the run's report (the command line passes
    :func:`reports.write_run_report` when ``report=true``); results.json is written last.
    """
    t_imports = import_libraries(cfg)
    t0 = time.perf_counter()
    run_dir = Path(run_dir)
    jit = CompileTimer().__enter__()      # Dr.Jit's compilation, inside total, reported apart
    try:
        problem, method, t_observe = prepare(cfg, run_dir)
        result, segment_maps = _solve(cfg, problem, method)
    finally:
        jit.__exit__(None, None, None)
    result.timings_s["imports"] = t_imports
    return _write_run(cfg, run_dir, problem, result, segment_maps, t_observe, t0, jit.seconds, write_report)


def import_libraries(cfg: DictConfig) -> float:
    """Import the libraries a run needs (Mitsuba, Open3D, pycolmap, the method's module) before
    the run's clock starts, and return the seconds it took (0 once imported).

    The first run of a process would otherwise count them (about 2.6 s: Open3D 1.3, Mitsuba 0.4,
    the methods and SciPy 1) in its total, and the later runs of a sweep not: a sweep's first
    method would look slower than it is. Results.json ``timings_s.imports``, outside ``total``.
    """
    t = time.perf_counter()
    backend.point_at_libllvm()              # before Dr.Jit's first import (libLLVM 15 aborts it)
    import mitsuba  # noqa: F401
    import open3d  # noqa: F401
    import pycolmap  # noqa: F401
    try:
        get_method(str(cfg.method.name))
    except ConfigError:
        pass                                # reported by prepare, with the other settings
    return time.perf_counter() - t


def _solve(cfg: DictConfig, problem: Problem, method: Method):
    """The method's result and the segment map of each view (the rendering part of a run)."""
    scene, cameras, settings = problem.scene, problem.cameras, problem.settings
    log.info("method %s on %s (%d view(s), %d parameters)", cfg.method.name, scene.name,
             len(cameras), len(problem.parameters))
    result = method.run(problem)
    if result.renders > settings.budget_renders:
        raise RuntimeError(f"{cfg.method.name} spent {result.renders} renders, budget {settings.budget_renders}")
    return result, view_segment_maps(problem.scene, problem.cameras)


def _write_run(cfg, run_dir: Path, problem: Problem, result, segment_maps: dict, t_observe: float, t0: float,
               compile_s: float, write_report) -> dict:
    """The run folder's images, report and (last) results.json; the results dict."""
    scene, cameras, settings = problem.scene, problem.cameras, problem.settings
    result.timings_s["compile"] = compile_s
    t_holdout = time.perf_counter()
    holdout = holdout_entries(problem, result, problem.held_out, run_dir) if problem.held_out else []
    result.timings_s["holdout"] = time.perf_counter() - t_holdout
    result.timings_s.setdefault("observe", t_observe)
    result.timings_s["total"] = time.perf_counter() - t0
    summary = {"scene_dir": str(scene.root), "scene_hash": scene.content_hash, "views": [c.name for c in cameras],
               "holdout": [c.name for c in problem.held_out.cameras] if problem.held_out else [],
               "light": scene.light,
               "variant": settings.variant, "device": backend.device_name(settings.variant),
               "seed": settings.seed, "spp": settings.spp, "max_bounces": settings.max_bounces,
               "tail_bounces": settings.tail_bounces,
               "budget_renders": settings.budget_renders, "executor": settings.executor.name,
               "observe": OmegaConf.to_container(cfg.observe),
               "method_settings": OmegaConf.to_container(cfg.method, resolve=True)}
    views = write_view_images(run_dir, problem, result, segment_maps)
    relit = write_relit_images(run_dir, problem, result)
    results = results_dict(problem, result, method=str(cfg.method.name), settings=summary, views=views,
                           relit=relit)
    results["holdout"] = holdout
    if write_report is not None:
        t_report = time.perf_counter()
        write_report(run_dir, results)
        results["timings_s"]["report"] = time.perf_counter() - t_report
    write_results(run_dir, results)           # last: a run that failed leaves no results.json
    log.info("wrote %s", run_dir / "results.json")
    return results



