"""Relighting and reflectance (albedo) images from estimated kernel weights.

* :func:`relit_scene` swaps the scene's illumination: the non-area emitters (envmap, constant,
  directional) are replaced by a given list; area emitters riding on meshes are kept unless
  ``keep_area=False`` (then those meshes stop emitting). The result is a new :class:`Scene`
  (``dataclasses.replace``) with its own ``content_hash``, so caches never confuse the two.
* :func:`render_relit` renders views of a scene at weights ρ with Mitsuba's ``path``
  integrator (``max_depth`` -1: unbounded, as for the observations).
* :func:`reflectance_images` is the shadow-free reflectance image of a view: through each pixel
  centre, the segment seen (:meth:`MitsubaScene.segment_map`) and its weight. ``kind="diffuse"``
  (default) gives the segment's diffuse weight ρ_d (its albedo; 0 for a segment without a
  diffuse kernel), ``kind="total"`` the sum of its kernel weights (total directional-hemispherical
  reflectance of the kernel sum). Sky / emitter-only pixels are 0; pixels of a segment whose
  weight is unknown (NaN: unobservable) are NaN.
"""
from __future__ import annotations

import dataclasses
import hashlib

import numpy as np

from framework.options import ANY, choice, flag, nullable, number, option
from framework.render.mitsuba_scene import MitsubaScene
from framework.scene import Camera, Emitter, Scene


def sun(direction, irradiance, channels: tuple[str, ...]) -> Emitter:
    """A directional emitter; ``direction`` is where the light travels (sun -> scene), normalised;
    ``irradiance`` one number or one per channel."""
    d = np.asarray(direction, float)
    return Emitter(type="directional", direction=d / np.linalg.norm(d),
                   irradiance=_per_channel(irradiance, channels))


def sky(radiance, channels: tuple[str, ...]) -> Emitter:
    """A constant (uniform) sky of ``radiance`` (one number or one per channel)."""
    return Emitter(type="constant", radiance=_per_channel(radiance, channels))


def _per_channel(value, channels) -> np.ndarray:
    v = np.atleast_1d(np.asarray(value, float))
    return np.broadcast_to(v, (len(channels),)).copy() if v.size == 1 else v.reshape(len(channels))


def relit_scene(scene: Scene, emitters: list[Emitter], *, keep_area: bool = True) -> Scene:
    """``scene`` under other illumination.

    Parameters
    ----------
    scene : Scene
    emitters : list of Emitter
        Replacement non-area emitters (``constant``, ``directional``, ``envmap``).
    keep_area : bool
        Keep the area emitters on meshes (default); False switches them off.

    Returns
    -------
    Scene
        A copy with the new emitters and a ``content_hash`` derived from the old one and the
        new illumination.
    """
    if any(e.type == "area" for e in emitters):
        raise ValueError("relit_scene: area emitters ride on meshes; pass only envmap/constant/directional")
    area = tuple(e for e in scene.emitters if e.type == "area") if keep_area else ()
    meshes = scene.meshes if keep_area else tuple(dataclasses.replace(m, radiance=None) for m in scene.meshes)
    h = hashlib.sha256(scene.content_hash.encode())
    for e in emitters:
        h.update(repr((e.type, e.scale, e.file)).encode())
        for a in (e.radiance, e.direction, e.irradiance, e.image):
            h.update(b"-" if a is None else np.ascontiguousarray(a, np.float64).tobytes())
    h.update(str(keep_area).encode())
    return dataclasses.replace(scene, emitters=tuple(emitters) + area, meshes=meshes,
                               content_hash=h.hexdigest()[:16])


def render_relit(scene: Scene, cameras: list[Camera], rho: np.ndarray, parameters, *, spp: int,
                 seed: int, max_depth: int = -1) -> dict[str, np.ndarray]:
    """Path-traced (H, W, C) images of ``cameras`` of ``scene`` at weights ``rho`` (P, C).

    NaN weights (unobservable parameters) are rendered as 0. View ``i`` uses Mitsuba seed
    ``seed + i``.
    """
    ms = MitsubaScene(scene, cameras, spp=spp, integrator={"type": "path", "max_depth": int(max_depth)})
    ms.set_weights(np.nan_to_num(np.asarray(rho, float)), parameters)
    return {c.name: ms.render(i, spp=spp, seed=int(seed) + i) for i, c in enumerate(cameras)}


def reflectance_images(scene: Scene, cameras: list[Camera], rho: np.ndarray, parameters, *,
                       kind: str = "diffuse") -> dict[str, np.ndarray]:
    """Shadow-free reflectance (H, W, C) float32 of each view (see the module docstring)."""
    table = segment_reflectance(scene, rho, parameters, kind=kind)          # (S + 1, C), row -1 = sky
    ms = MitsubaScene(scene, cameras, spp=1)
    return {c.name: table[ms.segment_map(i)].astype(np.float32) for i, c in enumerate(cameras)}


def segment_reflectance(scene: Scene, rho: np.ndarray, parameters, *, kind: str = "diffuse") -> np.ndarray:
    """``(S + 1, C)``: reflectance of each segment, last row 0 (indexed by segment map value -1)."""
    if kind not in ("diffuse", "total"):
        raise ValueError(f"kind={kind}: use diffuse or total")
    rho = np.asarray(rho, float)
    table = np.zeros((len(scene.segments) + 1, rho.shape[1]))
    for p in parameters:
        if kind == "total" or p.kernel == "diffuse":
            table[p.segment] += rho[p.index]                                  # NaN propagates
    return table


@dataclasses.dataclass(frozen=True)
class RelightOptions:
    """``method.relight.*``: images under other illumination with the estimated weights."""

    enabled: bool = option("after the inversion, render relit and reflectance images (not counted in "
                           "`renders`, timed as `timings_s.relight`)", flag(), default=False)
    sun_direction: tuple | None = option("direction the new sunlight travels; `null` keeps the scene's "
                                         "directional emitters", nullable(ANY), default=None)
    sun_irradiance: float | tuple | None = option("the new sun's irradiance (a number or one per channel); "
                                                  "`null`: the scene's first sun's, else 1", nullable(ANY),
                                                          default=None)
    sky_radiance: float | tuple | None = option("a constant sky (a number or one per channel) replacing the "
                                                "scene's `constant`/`envmap` skies; `null` keeps them",
                                                nullable(ANY), default=None)
    spp: int = option("samples per pixel of the relit images", number(1, integer=True), default=64)
    reflectance: str = option("the shadow-free reflectance image: each pixel's segment ρ_d (`diffuse`), or "
                              "Σρ over its kernels (`total`)", choice("diffuse", "total"), default="diffuse")


def relight_outputs(problem, parameters, estimate: np.ndarray, opt: RelightOptions) -> dict[str, np.ndarray]:
    """The images of the symbolic method's ``relight`` option (:class:`RelightOptions`), keyed
    ``<view>.relit`` and ``<view>.reflectance``.

    Seeds: ``2 * problem.seed + 100_001`` + view index (never an inversion's even seed stream).
    """
    scene = problem.scene
    new = relight_emitters(scene, opt)
    relit = relit_scene(scene, new)
    images = render_relit(relit, problem.cameras, estimate, parameters, spp=opt.spp,
                          seed=2 * int(problem.seed) + 100_001)
    albedo = reflectance_images(scene, problem.cameras, estimate, parameters,
                                kind=opt.reflectance)
    out = {}
    for c in problem.cameras:
        out[f"{c.name}.relit"] = images[c.name]
        out[f"{c.name}.reflectance"] = albedo[c.name]
    return out


def relight_emitters(scene: Scene, opt: RelightOptions) -> list[Emitter]:
    """Replacement non-area emitters of the ``relight`` options (:class:`RelightOptions`)."""
    ch = scene.channels
    suns = [e for e in scene.emitters if e.type == "directional"]
    skies = [e for e in scene.emitters if e.type in ("constant", "envmap")]
    if opt.sun_direction is not None:
        irr = opt.sun_irradiance
        if irr is None:
            irr = suns[0].irradiance if suns else 1.0
        irr = list(irr) if not isinstance(irr, (int, float)) else irr
        suns = [sun(list(opt.sun_direction), irr, ch)]
    if opt.sky_radiance is not None:
        rad = opt.sky_radiance
        skies = [sky(list(rad) if not isinstance(rad, (int, float)) else rad, ch)]
    return skies + suns
