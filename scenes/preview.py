"""Quick Mitsuba renders of a scene folder, independent of the framework's scene builder.

Used to write ``preview.png`` and by the tests: shapes are ``ply`` files with the reference
kernel BRDF (:func:`framework.kernels.forward_bsdf`), emitters as in ``scene.yaml``, and a
``perspective`` sensor from the COLMAP view (box filter).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from framework.render.backend import set_variant
from framework.render.envmap import TO_WORLD
from framework.kernels import forward_bsdf, spectrum, weight_values
from scenes.cameras import perspective_sensor
from framework.images import read_exr
from scenes.io import PinholeCamera, read_colmap


def load_yaml(folder: Path) -> dict:
    """The parsed ``scene.yaml`` of ``folder``."""
    return yaml.safe_load((Path(folder) / "scene.yaml").read_text())


def channels_of(scene: dict) -> tuple[str, ...]:
    """('R', 'G', 'B') or ('Y',)."""
    return ("Y",) if scene["channels"] == "mono" else ("R", "G", "B")


def select_variant(folder: Path) -> tuple[str, ...]:
    """Set the llvm variant matching the scene's channels; returns the channels."""
    ch = channels_of(load_yaml(folder))
    set_variant("llvm_ad_mono" if ch == ("Y",) else "llvm_ad_rgb")
    return ch


def _emitter(folder: Path, e: dict, ch: tuple[str, ...], area: dict[str, dict]) -> dict | None:
    import mitsuba as mi

    if e["type"] == "envmap":
        img = read_exr(folder / e["file"])
        if ch == ("Y",):
            img = img[..., 0]
        return {"type": "envmap", "bitmap": mi.Bitmap(np.ascontiguousarray(img, np.float32)),
                "scale": float(e.get("scale", 1.0)), "to_world": mi.ScalarTransform4f(TO_WORLD.tolist())}
    if e["type"] == "constant":
        return {"type": "constant", "radiance": spectrum(e["radiance"], ch)}
    if e["type"] == "directional":
        return {"type": "directional", "direction": [float(x) for x in e["direction"]],
                "irradiance": spectrum(e["irradiance"], ch)}
    if e["type"] == "area":
        for m in e["meshes"]:
            area[m] = {"type": "area", "radiance": spectrum(e["radiance"], ch)}
        return None
    raise ValueError(f"unknown emitter type {e['type']}")


def scene_dict(folder: Path, cam: PinholeCamera, spp: int = 16, seed: int = 0,
               integrator: dict | None = None) -> dict:
    """Mitsuba scene dict of the folder seen from ``cam``; shape keys are ``<segment>__<i>``
    (i: the mesh's index in the segment).

    The current variant must match the scene's channels (:func:`select_variant`).
    """
    folder = Path(folder)
    scene = load_yaml(folder)
    ch = channels_of(scene)
    area: dict[str, dict] = {}
    d = {"type": "scene", "integrator": integrator or {"type": "path", "max_depth": 4},
         "sensor": perspective_sensor(cam, spp, seed)}
    for i, e in enumerate(scene.get("emitters", [])):
        em = _emitter(folder, e, ch, area)
        if em is not None:
            d[f"emitter_{i}"] = em
    for seg in scene["segments"]:
        for k, m in enumerate(seg["meshes"]):
            d[f"{seg['name']}__{k}"] = {"type": "ply", "filename": str(folder / m), "face_normals": True,
                                       "bsdf": forward_bsdf(seg["kernels"], ch), **({"emitter": area[m]} if m in area else {})}
    return d


def load(folder: Path, cam: PinholeCamera, **kw):
    """Loaded Mitsuba scene with the segments' reference reflectances set."""
    import mitsuba as mi

    folder = Path(folder)
    ch = channels_of(load_yaml(folder))
    scene = mi.load_dict(scene_dict(folder, cam, **kw), optimize=False)
    params = mi.traverse(scene)
    for seg in load_yaml(folder)["segments"]:
        ref = seg.get("reference") or {}
        rho = np.array([np.broadcast_to(np.asarray(ref.get(k, 0.0), float), (len(ch),)) for k in seg["kernels"]])
        for k in range(len(seg["meshes"])):
            for key, value in weight_values(seg["kernels"], rho):
                full = f"{seg['name']}__{k}.bsdf.{key}"
                params[full] = float(value[0]) if ch == ("Y",) else mi.Color3f(*[float(x) for x in value])
    params.update()
    return scene


def render(folder: Path, view: int = 0, spp: int = 16, size: int | None = None, seed: int = 0,
           max_depth: int = 4) -> np.ndarray:
    """Render view ``view`` (index in the COLMAP model) at ``size`` pixels wide; (h, w, c) array."""
    select_variant(folder)          # before importing mitsuba: it picks the libLLVM
    import mitsuba as mi

    cam = resized(read_colmap(Path(folder) / "sparse")[view], size)
    scene = load(folder, cam, spp=spp, seed=seed, integrator={"type": "path", "max_depth": max_depth})
    img = np.array(mi.render(scene, seed=seed))
    return img.reshape(img.shape[0], img.shape[1], -1)


def resized(cam: PinholeCamera, size: int | None) -> PinholeCamera:
    """The same view at ``size`` pixels wide (focal scaled; square-pixel aspect kept)."""
    if size is None or size == cam.width:
        return cam
    s = size / cam.width
    return PinholeCamera(cam.name, size, max(1, round(cam.height * s)), cam.focal * s, cam.cam_from_world)


def segment_ids(folder: Path, cam: PinholeCamera) -> np.ndarray:
    """Per-pixel segment index (h, w) of the first hit at pixel centres; -1 where no shape is hit."""
    select_variant(folder)          # before importing mitsuba: it picks the libLLVM
    import drjit as dr
    import mitsuba as mi

    names = [s["name"] for s in load_yaml(folder)["segments"]]
    scene = mi.load_dict(scene_dict(folder, cam, spp=1), optimize=False)
    table = {int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(s))[0]): names.index(s.id().rsplit("__", 1)[0])
             for s in scene.shapes()}
    j, i = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    sensor = scene.sensors()[0]
    pos = mi.Point2f((j.ravel() / cam.width).astype(np.float32), (i.ravel() / cam.height).astype(np.float32))
    ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
    si = scene.ray_intersect(ray)
    reg = np.array(dr.reinterpret_array(mi.UInt32, si.shape))
    valid = np.array(si.is_valid())
    out = np.array([table.get(int(r), -1) for r in reg])
    out[~valid] = -1
    return out.reshape(cam.height, cam.width)


def tonemap(img: np.ndarray) -> np.ndarray:
    """uint8 sRGB preview: clip(x / 99th percentile) with the sRGB transfer curve."""
    x = np.clip(img / max(float(np.percentile(img, 99)), 1e-8), 0, 1)
    x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    x = (x * 255 + 0.5).astype(np.uint8)
    return np.repeat(x, 3, axis=2) if x.shape[2] == 1 else x


def write_png(path: Path, img: np.ndarray) -> Path:
    """Write a tonemapped PNG of a linear image (h, w, c)."""
    import mitsuba as mi

    mi.Bitmap(np.ascontiguousarray(tonemap(img))).write(str(path))
    return Path(path)


def write_preview(folder: Path, views: list[int] | None = None, size: int = 64, spp: int = 32) -> Path:
    """Render the given views (default: all) side by side into ``folder/preview.png``."""
    folder = Path(folder)
    n = len(read_colmap(folder / "sparse"))
    tiles = [render(folder, v, spp=spp, size=size) for v in (views if views is not None else range(n))]
    h = max(t.shape[0] for t in tiles)
    row = np.concatenate([np.pad(t, ((0, h - t.shape[0]), (0, 2), (0, 0))) for t in tiles], axis=1)
    return write_png(folder / "preview.png", row)
