"""``urban_canyon_glossy``: :mod:`scenes.urban_canyon` whose glass and walls are glossy, not mirrors.

Same meshes, segments, sky, sun and nine views as ``urban_canyon``. The truth differs in two
segments, whose mirror weight moves to a GGX lobe (:mod:`framework.brdf_kernels`, ``glossy(α)``):

* ``window``: kernels ``[diffuse, specular, glossy(0.05)]``, reference diffuse as urban_canyon,
  specular 0, ``glossy(0.05)`` 0.72 (slightly rough glass);
* ``wall``: kernels ``[diffuse, specular, glossy(0.3)]``, reference diffuse as urban_canyon,
  specular 0, ``glossy(0.3)`` 0.08 (a satin coat);
* every other segment ``[diffuse, specular]`` with urban_canyon's references.

The observations are part of the folder: ``images/<view>.exr``, path traced at the true weights
(Mitsuba ``path``, unbounded depth, Russian roulette from depth 5, ``spp`` samples, box filter;
half-float EXR),
so that fits with other kernel sets (a variant folder with other ``kernels`` and the same
``images/``) fit the same photographs; the loader then renders nothing and the run's
``observe.*`` settings do not apply. Deterministic for a given ``seed`` on one machine (each
view is one Mitsuba render of its own seed).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from framework.scene.write import write_colmap, write_scene_yaml
from scenes import urban_canyon as uc

WINDOW_ALPHA, WALL_ALPHA = 0.05, 0.3
IMAGE, SPP, SEED = uc.IMAGE, 1024, 0


def glossy_name(alpha: float) -> str:
    """The kernel name of a GGX lobe of roughness ``alpha`` (canonical: ``repr`` of the float)."""
    return f"glossy({float(alpha)!r})"


#: segment -> (kernels, reference) where they differ from urban_canyon
GLOSSY_SEGMENTS = {
    "window": (WINDOW_ALPHA, uc.REFERENCES["window"][1]),     # the mirror's 0.72 becomes glossy
    "wall": (WALL_ALPHA, uc.REFERENCES["wall"][1]),           # the mirror's 0.08 becomes satin
}


def segments(files: dict[str, list[str]]) -> list[dict]:
    """scene.yaml ``segments``: urban_canyon's rgb ones, window and wall glossy (module docstring)."""
    out = []
    for name, (rgb_d, rgb_s, _, _) in uc.REFERENCES.items():
        kernels, ref = ["diffuse", "specular"], {"diffuse": rgb_d, "specular": rgb_s}
        if name in GLOSSY_SEGMENTS:
            alpha, weight = GLOSSY_SEGMENTS[name]
            kernels.append(glossy_name(alpha))
            ref = {"diffuse": rgb_d, "specular": 0.0, glossy_name(alpha): weight}
        out.append({"name": name, "meshes": files[name], "kernels": kernels, "reference": ref})
    return out


def render_observations(folder: Path, *, spp: int, seed: int) -> dict[str, float]:
    """Path trace every view of the scene in ``folder`` at its references into
    ``images/<view stem>.exr``; returns seconds per view."""
    from framework.render.backend import set_variant
    from framework.render.mitsuba_scene import MitsubaScene
    from framework.scene import load_scene

    scene = load_scene(folder)                 # before images/ exists: references, no photographs
    (folder / "images").mkdir(parents=True, exist_ok=True)
    set_variant("auto", channels=scene.channels)
    ms = MitsubaScene(scene, list(scene.cameras), spp=spp, integrator={"type": "path", "max_depth": -1})
    params = scene.parameters()
    ms.set_weights(scene.reference(params), params)
    seconds = {}
    for i, cam in enumerate(scene.cameras):
        t0 = time.perf_counter()
        img = ms.render(i, spp=spp, seed=2 * (seed * 1009 + i) + 1)
        write_half_exr(folder / "images" / f"{Path(cam.name).stem}.exr", img)
        seconds[cam.name] = time.perf_counter() - t0
    return seconds


def write_half_exr(path: Path, image: np.ndarray) -> None:
    """An (H, W, 3) image as a half-float RGB EXR (ZIP): half the bytes of float32 (165 kB a
    200x200 view), and its rounding (relative <= 2^-11) is far below the renders' noise."""
    import OpenEXR

    planes = {name: np.ascontiguousarray(image[..., i], dtype=np.float16) for i, name in enumerate("RGB")}
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, planes) as exr:
        exr.write(str(path))


def build(folder: Path, *, image: int = IMAGE, spp: int = SPP, seed: int = SEED) -> Path:
    """Write the scene folder: urban_canyon's geometry, light and views with the glossy truth,
    and its observed images.

    Parameters
    ----------
    folder : Path
        Output folder (created).
    image : int
        Width and height of the views (200 for the bundled scene; tests may use fewer).
    spp : int
        Samples per pixel of the observation renders.
    seed : int
        Seeds Mitsuba's sampler (view i uses ``2 (1009 seed + i) + 1``).
    """
    folder = Path(folder)
    files = {seg: uc.write_mesh_files(folder, parts) for seg, parts in uc.meshes().items()}
    emitters = uc.write_lighting(folder, "rgb")
    write_colmap(folder / "sparse", uc.cameras(8, image), uc.landmarks())
    scene = {"name": folder.name, "channels": "rgb", "segments": segments(files), "emitters": emitters}
    write_scene_yaml(folder / "scene.yaml", scene, _comment(spp, seed))
    render_observations(folder, spp=spp, seed=seed)
    return folder


def _comment(spp: int, seed: int) -> str:
    return f"""Generated by `python -m scenes.build urban_canyon_glossy` (scenes/urban_canyon_glossy.py); do not
edit by hand. urban_canyon (same meshes, sky.exr, sun and views) with glossy truth: window
glossy({WINDOW_ALPHA}) 0.72 and wall glossy({WALL_ALPHA}) 0.08 in place of their mirror weights (specular 0).
images/: Mitsuba path, unbounded depth, {spp} spp, seed {seed}, at these references."""
