"""One inversion run: load the scene, get the observations, run the method, write the run folder.

:func:`run_experiment` is what ``python -m framework.run`` calls inside Hydra; tests call it
directly with a composed config. Input checks come first; the run folder gets results.json
only when everything else succeeded.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

from omegaconf import DictConfig, OmegaConf, open_dict

from framework.errors import ConfigError

log = logging.getLogger(__name__)


def scene_dir(cfg: DictConfig) -> Path:
    """``scene.dir`` if given, else the bundled folder ``scenes/<scene.name>``."""
    if cfg.scene.get("dir"):
        return Path(str(cfg.scene.dir)).expanduser()
    from scenes import BUNDLED_DIR
    return Path(BUNDLED_DIR) / str(cfg.scene.name)


def check_settings(cfg: DictConfig) -> None:
    """Reject settings outside their range, naming the key and the allowed range."""
    checks = [("render.spp", cfg.render.spp, 1, None), ("render.max_bounces", cfg.render.max_bounces, 1, 8),
              ("render.tail_bounces", cfg.render.get("tail_bounces", 0), 0, 16),
              ("budget.renders", cfg.budget.renders, 1, None), ("observe.spp", cfg.observe.spp, 1, None)]
    for key, value, lo, hi in checks:
        if not isinstance(value, int) or value < lo or (hi is not None and value > hi):
            rng = f"[{lo}, {hi}]" if hi is not None else f">= {lo}"
            raise ConfigError(f"{key}={value} is out of range: use an integer {rng}")
    if cfg.observe.noise < 0:
        raise ConfigError(f"observe.noise={cfg.observe.noise} is negative: use a value >= 0")


def select_cameras(scene, cfg: DictConfig) -> list:
    views = cfg.views
    if views == "default":
        views = cfg.scene.get("views", "all") if not cfg.scene.get("dir") else "all"
    if views == "all":
        return list(scene.cameras)
    if isinstance(views, str):
        views = [views]
    return [scene.camera(str(v)) for v in views]


def run_experiment(cfg: DictConfig, run_dir: str | Path) -> dict:
    """Run ``cfg.method`` on ``cfg.scene``; write the run folder; return the results dict."""
    from framework.render import backend
    from framework.cache import Cache
    from framework.registry import Problem, get_method
    from framework.observe import observed_images
    from framework.results import results_dict, write_relit_images, write_results, write_view_images
    from framework.scene import load_scene

    t0 = time.perf_counter()
    run_dir = Path(run_dir)
    check_settings(cfg)
    method_cls = get_method(str(cfg.method.name))
    scene = load_scene(scene_dir(cfg))
    variant = backend.set_variant(str(cfg.variant), channels=scene.channels)
    with open_dict(cfg):
        cfg.variant_resolved = variant
    cameras = select_cameras(scene, cfg)
    cache = Cache(cfg.cache.dir)
    observed, t_observe = observed_images(scene, cameras, cfg, cache=cache)
    problem = Problem(scene=scene, cameras=cameras, observed=observed, parameters=scene.parameters(),
                      settings=cfg, seed=int(cfg.seed))
    method = method_cls(cfg.method)
    log.info("method %s on %s (%d view(s), %d parameters)", cfg.method.name, scene.name,
             len(cameras), len(problem.parameters))
    result = method.run(problem)
    if result.renders > cfg.budget.renders:
        raise RuntimeError(f"{cfg.method.name} spent {result.renders} renders, budget {cfg.budget.renders}")

    segment_maps = _segment_maps(scene, cameras)
    result.timings_s.setdefault("observe", t_observe)
    result.timings_s["total"] = time.perf_counter() - t0
    settings = {"scene_dir": str(scene.root), "views": [c.name for c in cameras], "variant": variant,
                "seed": int(cfg.seed), "spp": int(cfg.render.spp), "max_bounces": int(cfg.render.max_bounces),
                "budget_renders": int(cfg.budget.renders), "executor": str(cfg.executor.name),
                "observe": OmegaConf.to_container(cfg.observe),
                "method_settings": OmegaConf.to_container(cfg.method, resolve=True)}
    views = write_view_images(run_dir, problem, result, segment_maps)
    relit = write_relit_images(run_dir, problem, result)
    results = results_dict(problem, result, method=str(cfg.method.name), settings=settings, views=views,
                           relit=relit)
    if cfg.get("report", True):
        from reports import write_run_report
        t_report = time.perf_counter()
        write_run_report(run_dir, results)
        results["timings_s"]["report"] = time.perf_counter() - t_report
    write_results(run_dir, results)           # last: a run that failed leaves no results.json
    log.info("wrote %s", run_dir / "results.json")
    return results


def _segment_maps(scene, cameras) -> dict:
    from framework.render.mitsuba_scene import MitsubaScene
    ms = MitsubaScene(scene, cameras, spp=1)
    return {c.name: ms.segment_map(i) for i, c in enumerate(cameras)}
