"""One inversion run: load the scene, get the observations, run the method, write the run folder.

:func:`run_experiment` is what ``python -m framework.run`` calls inside Hydra; tests call it
directly with a composed config. Input checks come first; the run folder gets results.json
only when everything else succeeded.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Callable

from omegaconf import DictConfig, OmegaConf

from framework.cache import Cache
from framework.config import RunSettings, scene_dir
from framework.observe import observed_images
from framework.registry import Method, Problem, get_method
from framework.render import backend
from framework.render.mitsuba_scene import MitsubaScene
from framework.results import results_dict, write_relit_images, write_results, write_view_images
from framework.scene import load_scene

log = logging.getLogger(__name__)


def select_cameras(scene, cfg: DictConfig) -> list:
    views = cfg.views
    if views == "default":
        views = cfg.scene.get("views", "all") if not cfg.scene.get("dir") else "all"
    if views == "all":
        return list(scene.cameras)
    if isinstance(views, str):
        views = [views]
    return [scene.camera(str(v)) for v in views]


def prepare(cfg: DictConfig) -> tuple[Problem, Method, float]:
    """The problem and the method of a composed configuration, and the seconds spent rendering
    observations (0 when cached): the settings checked, the scene loaded, the variant set, the
    views selected, the observations read or rendered. ConfigError/SceneError on bad input."""
    RunSettings.from_config(cfg)                # range checks before anything is loaded
    method_cls = get_method(str(cfg.method.name))
    scene = load_scene(scene_dir(cfg))
    variant = backend.set_variant(str(cfg.variant), channels=scene.channels)
    settings = RunSettings.from_config(cfg, variant=variant)
    cameras = select_cameras(scene, cfg)
    observed, t_observe = observed_images(scene, cameras, settings, cache=Cache(settings.cache_dir))
    problem = Problem(scene=scene, cameras=cameras, observed=observed, parameters=scene.parameters(),
                      settings=settings)
    return problem, method_cls(cfg.method), t_observe


def run_experiment(cfg: DictConfig, run_dir: str | Path, *,
                   write_report: Callable[[Path, dict], object] | None = None) -> dict:
    """Run ``cfg.method`` on ``cfg.scene``; write the run folder; return the results dict.

    ``write_report(run_dir, results)`` writes the run's report (the command line passes
    :func:`reports.write_run_report` when ``report=true``); results.json is written last.
    """
    t0 = time.perf_counter()
    run_dir = Path(run_dir)
    problem, method, t_observe = prepare(cfg)
    scene, cameras, settings = problem.scene, problem.cameras, problem.settings
    log.info("method %s on %s (%d view(s), %d parameters)", cfg.method.name, scene.name,
             len(cameras), len(problem.parameters))
    result = method.run(problem)
    if result.renders > settings.budget_renders:
        raise RuntimeError(f"{cfg.method.name} spent {result.renders} renders, budget {settings.budget_renders}")

    segment_maps = _segment_maps(scene, cameras)
    result.timings_s.setdefault("observe", t_observe)
    result.timings_s["total"] = time.perf_counter() - t0
    summary = {"scene_dir": str(scene.root), "views": [c.name for c in cameras], "variant": settings.variant,
               "seed": settings.seed, "spp": settings.spp, "max_bounces": settings.max_bounces,
               "budget_renders": settings.budget_renders, "executor": str(settings.executor.get("name")),
               "observe": OmegaConf.to_container(cfg.observe),
               "method_settings": OmegaConf.to_container(cfg.method, resolve=True)}
    views = write_view_images(run_dir, problem, result, segment_maps)
    relit = write_relit_images(run_dir, problem, result)
    results = results_dict(problem, result, method=str(cfg.method.name), settings=summary, views=views,
                           relit=relit)
    if write_report is not None:
        t_report = time.perf_counter()
        write_report(run_dir, results)
        results["timings_s"]["report"] = time.perf_counter() - t_report
    write_results(run_dir, results)           # last: a run that failed leaves no results.json
    log.info("wrote %s", run_dir / "results.json")
    return results


def _segment_maps(scene, cameras) -> dict:
    ms = MitsubaScene(scene, cameras, spp=1)
    return {c.name: ms.segment_map(i) for i, c in enumerate(cameras)}
