"""Held-out views (``holdout=[NAME, ...]``): read and checked like the fitted views, not fitted,
predicted at the estimate and compared with their photographs (results.json ``holdout``).

The prediction is a Mitsuba ``path`` render at the estimate (:func:`framework.relight.render_relit`)
at the observations' spp and depth (``observe.spp``, ``observe.max_depth``), integrated over the
footprint of the photograph's resampling where the loader resampled it from a distorted camera
(:mod:`framework.holdout_footprint`), times the exposure
gain and the lens falloff the fitted views get: a held-out view has no gain of its own, so where
the method estimated per-view gains the view's is fitted to its photograph (:func:`held_out_gain`;
1 where it estimated none), and the vignetting profile of its lens (scene.yaml's, or the one the fit estimated). An
emitter of unknown scale shines at the scale the fit estimated (:func:`estimated_light`).

A view photographed under another light than the fitted views' (scene.yaml ``lights``) is
predicted under its own light as declared: relighting. Its light must then be known (no emitter
of unknown scale: no fitted view could estimate it, :func:`held_out_scenes`); the fitted views
all share one light (:func:`fitted_light`), and the fit sees that light alone.

Image-space std (``z_rms``): each pixel's predicted variance is the delta method through the
pixel at the estimate, ``J Σ Jᵀ`` per channel (``J`` the pixel's derivatives in the weights,
``Σ`` the parameters' covariance from the method's ``std`` and ``correlation``), plus the
observation noise the fit left (the mean squared residual of the fitted views' reconstructions
over their used pixels, per channel, less the reconstructions' own Monte Carlo variance, which a
method reports from two independent halves of its samples), plus the prediction's own Monte Carlo
variance (from two half-spp renders). ``J`` comes from forward differences of ``path`` renders that share their
random numbers (``docs/design-notes.md``). A method without a std gets the noise terms alone.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from omegaconf import DictConfig, OmegaConf

from framework.errors import ConfigError
from framework.holdout_footprint import render_resampled

#: Step of the forward differences in the weights (the pixel is a polynomial of low degree in
#: them, so the truncation error is of this order relative to the derivative).
FD_STEP = 0.02
#: Seed stream of the predictions (never an inversion's even seeds nor the observations').
PREDICTION_SEED = 500_009


@dataclass
class HeldOut:
    """The held-out views of a run: cameras, photographs and pixel weights (None: all count)."""

    cameras: list
    observed: dict
    weights: dict | None = None
    #: view -> the scene it is lit by, for the views photographed under another light than the
    #: fitted ones (:func:`held_out_scenes`); the others are lit by the problem's scene
    scenes: dict | None = None

    def scene_of(self, name: str, default):
        """The scene view ``name`` is lit by: its own light's, or ``default`` (the fit's)."""
        return (self.scenes or {}).get(name, default)

    def used(self, name: str) -> np.ndarray:
        """``(H, W)`` bool: the pixels of view ``name`` the run would have used."""
        image = self.observed[name]
        if self.weights is None or name not in self.weights:
            return np.ones(image.shape[:2], bool)
        return np.asarray(self.weights[name]) > 0


def holdout_names(cfg: DictConfig) -> list[str]:
    """The view names of ``holdout`` (default ``[]``); ConfigError for a name listed twice."""
    value = cfg.get("holdout") or []
    names = [str(v) for v in value] if OmegaConf.is_list(value) or isinstance(value, list) else [str(value)]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ConfigError(f"holdout lists {', '.join(twice)} more than once: name each view once")
    return names


def split_holdout(scene, cameras: list, names: list[str]) -> tuple[list, list]:
    """``(fitted, held_out)`` cameras: ``names`` taken out of the selected ``cameras`` (a scene view
    not selected by ``views`` may be held out too). ConfigError for a name that is not a view of
    the scene, or when no view is left to fit."""
    views = [c.name for c in scene.cameras]
    for name in names:
        if name not in views:
            shown = ", ".join(views[:8]) + (", ..." if len(views) > 8 else "")
            raise ConfigError(f"holdout names {name}, which is not a view of scene {scene.name}: "
                              f"name one of its views ({shown})")
    fitted = [c for c in cameras if c.name not in names]
    if names and not fitted:
        raise ConfigError(f"holdout=[{', '.join(names)}] holds out every selected view, leaving none to fit: "
                          "hold out fewer views, or select more with views=")
    return fitted, [scene.camera(n) for n in names]


def light_label(light: str | None) -> str:
    """A light in a message: ``light 'name'``, or scene.yaml's emitters for None."""
    return "scene.yaml emitters" if light is None else f"light '{light}'"


def fitted_light(scene, cameras: list) -> str | None:
    """The light the fitted ``cameras`` were photographed under (:meth:`Scene.light_of`); a
    ConfigError when they span two lights (a fit sees one light)."""
    groups: dict = {}
    for c in cameras:
        groups.setdefault(scene.light_of(c.name), []).append(c.name)
    if len(groups) > 1:
        shown = "; ".join(f"{light_label(k)}: {', '.join(v[:3])}{', ...' if len(v) > 3 else ''}"
                          for k, v in groups.items())
        raise ConfigError(f"views selects photographs of {len(groups)} lights ({shown}), and a fit takes the views "
                          "of one light: select one light's views (views=[...]) and hold out the others "
                          "(holdout=[...]) to predict them under their own light")
    return next(iter(groups), None)


def held_out_scenes(scene, fit_scene, held: list) -> dict:
    """View -> the scene (loaded ``scene`` under the view's light, :meth:`Scene.under`) of each
    held-out view photographed under another light than the fit's (``fit_scene.light``).
    ConfigError for such a light with an emitter of unknown scale: no fitted view estimates it."""
    out = {}
    for cam in held:
        light = scene.light_of(cam.name)
        if light == fit_scene.light:
            continue
        lit = scene.under(light)
        unknown = next((e for e in lit.emitters if e.scale_unknown), None)
        if unknown is not None:
            key = "scale" if unknown.part is None else f"{unknown.part}_scale"
            kind = "sunsky" if unknown.part is not None else unknown.type
            raise ConfigError(f"holdout view {cam.name} was photographed under {light_label(light)}, whose emitter "
                              f"{unknown.source} ({kind}) {key} is unknown, and the fitted views (under "
                              f"{light_label(fit_scene.light)}) cannot estimate it: give {key} as a number in "
                              f"{light_label(light)}, or fit views of that light")
        out[cam.name] = lit
    return out


def check_held_out(scene, held: list, scenes: dict | None = None) -> None:
    """ConfigError for a held-out view that could not be compared with its prediction: no usable
    pixel, or (:func:`framework.render.checks.check_views` on the view alone, under its own light:
    ``scenes``, :func:`held_out_scenes`, else ``scene``'s) only sky in its usable pixels, or no
    light on what it sees."""
    from framework.errors import SceneError
    from framework.render.checks import check_views
    for cam in held:
        weights = None if scene.weights is None else {cam.name: scene.weights[cam.name]}
        if weights is not None and not np.any(np.asarray(weights[cam.name]) > 0):
            raise ConfigError(f"holdout view {cam.name} has no usable pixel (every pixel masked, saturated or "
                              "black), so there is nothing to compare its prediction with: hold out another view")
        try:
            check_views((scenes or {}).get(cam.name, scene), [cam], weights=weights)
        except SceneError as exc:
            raise ConfigError(f"holdout view {cam.name} cannot be compared with its prediction ({exc})") from None


def lens_falloff(scene, camera, extras: dict) -> np.ndarray | float:
    """The lens falloff ``1 + a1 r² + a2 r⁴ + a3 r⁶`` of ``camera``: scene.yaml's profile, or the
    one the fit estimated for the camera's lens (results.json ``vignetting``); 1 without one."""
    photometry = scene.photometry
    profile = photometry.vignetting_profile if photometry.vignetting == "known" else None
    for lens in extras.get("vignetting") or []:
        if str(lens.get("camera")) == str(getattr(camera, "camera_id", None)) and None not in lens["estimate"]:
            profile = lens["estimate"]
    if profile is None:
        return 1.0
    from framework.scene.lens import falloff, pixel_radius
    return falloff(pixel_radius(camera), profile).reshape(int(camera.height), int(camera.width), 1)


def estimated_light(scene, extras: dict):
    """``scene`` with each emitter of unknown scale multiplied by the scale the fit estimated
    (results.json ``illumination``, per channel; an emitter whose scale was not observable keeps
    its nominal light)."""
    import dataclasses
    import hashlib
    entries = [e for e in extras.get("illumination") or [] if e.get("estimate") and None not in e["estimate"]]
    if not entries:
        return scene
    emitters, h = list(scene.emitters), hashlib.sha256(scene.content_hash.encode())
    for entry in entries:
        k = np.asarray(entry["estimate"], float)
        for i, e in enumerate(emitters):
            if e.scale_unknown and e.source == entry["emitter"] and e.part == entry.get("part"):
                emitters[i] = dataclasses.replace(e, **{a: getattr(e, a) * (k if a != "image" else k[None, None])
                                                        for a in ("radiance", "irradiance", "image")
                                                        if getattr(e, a) is not None})
        h.update(k.tobytes())
    return dataclasses.replace(scene, emitters=tuple(emitters), content_hash=h.hexdigest()[:16])


def held_out_gain(extras: dict, observed: np.ndarray, prediction: np.ndarray, used: np.ndarray | None) -> np.ndarray:
    """``(C,)``: a held-out view's exposure gain. 1 when the method estimated none (the photographs
    share the fitted views' scale). Else the view has no gain of its own: it is fitted to the
    photograph, per channel, by least squares over the view's ``used`` pixels,
    ``g = Σ y p / Σ p²`` (``y`` the ``(H, W, C)`` photograph, ``p`` the unit-gain ``prediction``),
    as outdoor benchmarks fit a test image's appearance (three numbers against thousands of
    pixels). The fitted views' median gain, used before, was 21 % off street_004's in
    ``urban_canyon_field``, whose views' gains spread over a factor 3.4."""
    if not extras.get("exposure"):
        return np.ones(observed.shape[-1])
    y, p = (a.reshape(-1, a.shape[-1]) if used is None else a[used] for a in (observed, prediction))
    power = (p * p).sum(axis=0)
    return np.where(power > 0, (y * p).sum(axis=0) / np.where(power > 0, power, 1.0), 1.0)


def render_at(problem, cameras, rho, params, *, spp: int, seed: int) -> dict:
    """Unit-gain ``path`` renders of ``cameras`` at ``rho`` (rows in ``params`` order), at
    ``observe.max_depth``, resampled views through their footprint; view ``i`` seeded ``seed + i``."""
    obs = problem.settings.observe
    return render_resampled(problem.scene, cameras, rho, params, spp=spp, seed=seed, max_depth=obs.max_depth)


def predict(problem, cameras, rho, params) -> tuple[dict, dict]:
    """The unit-gain predictions of ``cameras`` at ``rho`` (rows in ``params`` order) and their
    per-channel Monte Carlo variance ``(C,)``: the mean of two half-spp renders, and a quarter of
    the mean squared difference of the two."""
    spp = max(1, problem.settings.observe.spp // 2)
    seed = 2 * int(problem.seed) + PREDICTION_SEED
    a = render_at(problem, cameras, rho, params, spp=spp, seed=seed)
    b = render_at(problem, cameras, rho, params, spp=spp, seed=seed + len(cameras))
    means = {n: 0.5 * (a[n] + b[n]) for n in a}
    mc_var = {n: ((a[n] - b[n]) ** 2).reshape(-1, a[n].shape[-1]).mean(axis=0) / 4.0 for n in a}
    return means, mc_var
