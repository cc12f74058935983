"""Observed images: the scene's own EXRs, or synthesised from its references (paper section 5.1).

Synthetic observations are rendered with Mitsuba's ``path`` integrator at the reference
weights (``observe.max_depth``: -1, unbounded, as real light is), through the scene's known
lens falloff (``photometry: vignetting: [a1, a2, a3]``), optionally with seeded Gaussian sensor
noise, and cached by everything that affects them, so a sweep renders them once.

Seeds: observations use odd seeds and the inversions' own renders even ones
(:func:`observation_seed`, :func:`inversion_seed`), so the two noises are never correlated
(the paper, section 5.1: the noise of the observations must not be the noise of the inversion).
"""
from __future__ import annotations

import logging
import time

import numpy as np

from framework.cache import Cache, code_version
from framework.memory import release_freed_memory
from framework.render.checks import check_memory, check_views, film_bytes
from framework.render.mitsuba_scene import MitsubaScene
from framework.scene import Camera, Scene
from framework.scene.lens import falloff, pixel_radius

log = logging.getLogger(__name__)
_SEED_SPACE = 2**31 - 1


def observation_seed(seed: int) -> int:
    """Odd Mitsuba seed for the synthetic observation stream ``seed``."""
    return (2 * int(seed) + 1) % _SEED_SPACE


def inversion_seed(seed: int, counter: int = 0) -> int:
    """Even Mitsuba seed for render ``counter`` of a run with seed ``seed``."""
    return (2 * (int(seed) * 1_000_003 + int(counter))) % _SEED_SPACE


def observed_images(scene: Scene, cameras: list[Camera], settings, *, cache: Cache, check: bool = True
                    ) -> tuple[dict[str, np.ndarray], float]:
    """Observed (H, W, C) images of ``cameras`` and the seconds spent rendering them (0 if cached).

    ``settings`` is the run's :class:`~framework.config.RunSettings`: its ``observe`` holds
    ``spp``, ``max_depth``, ``noise`` (std of additive Gaussian noise relative to the image mean)
    and ``seed``; the cache key includes its ``variant``.

    The views are checked first (:func:`framework.render.checks.check_views`, paths of any
    length), observed images or not: every method renders them next, and a view set that sees
    no lit segment is a :class:`~framework.errors.SceneError` here rather than a Dr.Jit failure
    there. ``check=False`` skips them (the caller checked the views, as
    :func:`framework.experiment.prepare` does with the scene's pixel weights).
    """
    if check:
        check_views(scene, cameras)
    if scene.images is not None:
        return {c.name: scene.images[c.name] for c in cameras}, 0.0
    obs = settings.observe
    out, todo = {}, []
    for c in cameras:
        key = _key(scene, c, obs, settings.variant)
        hit = cache.load("observed", key)
        if hit is not None:
            out[c.name] = hit["image"]
        else:
            todo.append(c)
    if not todo:
        return out, 0.0
    t0 = time.perf_counter()
    log.info("rendering %d observed view(s) at %d spp", len(todo), obs.spp)
    for c, img in zip(todo, render_references(scene, todo, spp=obs.spp, max_depth=obs.max_depth,
                                                seed=obs.seed, noise=obs.noise)):
        cache.store("observed", _key(scene, c, obs, settings.variant), {"image": img})
        out[c.name] = img
    return out, time.perf_counter() - t0


def render_references(scene: Scene, cameras: list[Camera], *, spp: int, max_depth: int, seed: int,
                      noise: float = 0.0) -> list[np.ndarray]:
    """Path-traced images of ``cameras`` at the scene's reference weights.

    Raises :class:`~framework.errors.ConfigError` before rendering when the films do not fit in
    memory (a path render's memory does not grow with ``spp``, only its time).
    """
    from tqdm import tqdm
    check_memory(film_bytes(cameras, len(scene.channels)), "the observation renders' films",
                 "resample the views to fewer pixels")
    ms = MitsubaScene(scene, cameras, spp=spp, integrator={"type": "path", "max_depth": int(max_depth)})
    params = scene.parameters()
    ms.set_weights(np.nan_to_num(scene.reference(params)), params)
    rng = np.random.default_rng(observation_seed(seed))
    images = []
    for i, cam in enumerate(tqdm(cameras, desc="observe", unit="view", leave=False)):
        img = ms.render(i, spp=spp, seed=observation_seed(seed * 7919 + i)) * lens_falloff(scene, cam)
        if noise > 0:
            img = np.maximum(img + rng.normal(0.0, noise * img.mean(), img.shape), 0.0)
        images.append(img.astype(np.float32))
    del ms
    # the renders' buffers stay in Dr.Jit's cache for reuse: hand them back before the method runs
    import drjit as dr
    dr.flush_malloc_cache()
    release_freed_memory()
    return images


def lens_falloff(scene: Scene, camera: Camera) -> np.ndarray | float:
    """``(H, W, 1)`` the known vignetting ``V(r)`` of scene.yaml's ``photometry`` at each pixel of
    ``camera``, or 1: an observation rendered from the references goes through the lens the fit
    divides out (:mod:`framework.scene.lens`); an estimated profile starts from no falloff."""
    photometry = getattr(scene, "photometry", None)
    if photometry is None or photometry.vignetting != "known":
        return 1.0
    factor = falloff(pixel_radius(camera), photometry.vignetting_profile)
    return factor.reshape(int(camera.height), int(camera.width), 1)


#: the code a cached observation depends on (:func:`~framework.cache.code_version`): the scene's
#: loading, the renderer and this module
OBSERVED_CODE = ("framework.observe", "framework.render", "framework.scene")


def _key(scene: Scene, cam: Camera, obs, variant: str) -> dict:
    photometry = getattr(scene, "photometry", None)
    lens = list(photometry.vignetting_profile) if photometry is not None and photometry.vignetting == "known" else None
    return {"scene": scene.content_hash, "view": cam.name, "spp": int(obs.spp),
            "max_depth": int(obs.max_depth), "noise": float(obs.noise), "seed": int(obs.seed),
            "variant": variant, "vignetting": lens, "code": code_version(*OBSERVED_CODE)}
