"""Quick renders of a scene folder through the framework: ``preview.png`` and the scene tests.

The folder is read by :func:`framework.scene.load_scene` and rendered at the segments' reference
weights by :func:`framework.observe.render_references` (a
:class:`~framework.render.mitsuba_scene.MitsubaScene` with ``path`` integrator); views are the
loaded cameras, in the loader's order (by name), resized with :func:`scenes.cameras.resized`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from framework.images import tonemap, write_png
from framework.observe import render_references
from framework.render.backend import set_variant
from framework.render.mitsuba_scene import MitsubaScene
from framework.scene import Camera, Scene, load_scene
from scenes.cameras import resized


def load(folder: Path) -> Scene:
    """The scene of ``folder``, with the variant of its channels selected (``variant=auto``) (before any Mitsuba use)."""
    scene = load_scene(folder)
    set_variant("auto", channels=scene.channels)
    return scene


def render(folder: Path, view: int | str = 0, spp: int = 16, size: int | None = None, seed: int = 0,
           max_depth: int = 4) -> np.ndarray:
    """Render one view at the reference weights; (h, w, c) float32 array.

    Parameters
    ----------
    folder : Path
        Scene folder.
    view : int or str
        Index into the loaded cameras (sorted by name) or an image name (``street_002.png``).
    spp, seed : int
        Samples per pixel and Mitsuba seed.
    size : int, optional
        Width in pixels (:func:`scenes.cameras.resized`); default the camera's own.
    max_depth : int
        Mitsuba ``path`` depth (``max_depth - 1`` reflections).
    """
    scene = load(folder)
    cam = scene.camera(view) if isinstance(view, str) else scene.cameras[view]
    return render_references(scene, [resized(cam, size)], spp=spp, max_depth=max_depth, seed=seed)[0]


def segment_ids(folder: Path, cam: Camera) -> np.ndarray:
    """Per-pixel segment index (h, w) seen through the pixel centres of ``cam``; -1 where none."""

    return MitsubaScene(load(folder), [cam], spp=1).segment_map(0)


def write_preview(folder: Path, views: list[str] | None = None, size: int = 64, spp: int = 32) -> Path:
    """Render the given views (default: all, by name) side by side into ``folder/preview.png``,
    each under the light it was photographed under (scene.yaml ``lights``)."""
    folder = Path(folder)
    scene = load(folder)
    cams = scene.cameras if views is None else [scene.camera(v) for v in views]
    by_light: dict = {}
    for c in cams:
        by_light.setdefault(scene.light_of(c.name), []).append(c)
    rendered = {c.name: tile for light, group in by_light.items()
                for c, tile in zip(group, render_references(scene.under(light), [resized(c, size) for c in group],
                                                            spp=spp, max_depth=4, seed=0))}
    tiles = [rendered[c.name] for c in cams]
    h = max(t.shape[0] for t in tiles)
    row = np.concatenate([np.pad(t, ((0, h - t.shape[0]), (0, 2), (0, 0))) for t in tiles], axis=1)
    write_png(folder / "preview.png", tonemap(row))
    return folder / "preview.png"
