"""``urban_canyon_field``: :mod:`scenes.urban_canyon` as a mobile-mapping camera delivers it.

Same meshes, segments, references, sky and sun and the same nine view poses as
``urban_canyon``, but the observations are field photographs (the scene format's field
photographs: distorted cameras, 8-bit sRGB JPEGs, per-view exposure, masks):

- Cameras: street views of even index and the aerial view are ``SIMPLE_RADIAL`` (k about -0.08),
  odd street views ``OPENCV`` with ``fx / fy`` about 1.02 (k1 -0.1, k2 0.02, p1, p2 about
  1e-3); principal points within 1.5 px (at 200 px) of the centre. Parameters are seeded.
- Rendering: each view is path traced (unbounded depth) at the true weights on a ``PINHOLE``
  camera of the same pose with twice the largest focal length, large enough that every
  distorted pixel's ray falls inside it (:func:`framework.scene.undistort.source_pixels`), then
  resampled onto the distorted camera with :func:`framework.scene.undistort.resample`
  (bilinear at the distorted pixel centres; no box average).
- Objects the model lacks, rendered into the photographs only (not in ``scene.yaml``): a parked
  car (boxes, dark paint with a mirror coat, at the north curb), masked in ``masks/``; a
  pedestrian in bright clothing on the sunlit side, not masked.
- Photometry: per-view, per-channel gains in [0.5, 2] (the reference view ``street_002.jpg`` has
  gains 1; three overexposed views have gains of about 3 to 3.7, so that their sunlit facade, sky
  or pedestrian clip: the model peaks at ~0.36 linear radiance), Gaussian sensor noise (1 % of the view's mean plus a shot term), sRGB encoding, clipping to
  [0, 1], 8 bits, JPEG quality 95 with 4:4:4 chroma.

The true gains, camera parameters, objects and clip counts are in ``truth.yaml`` (the loader
ignores it); ``README.md`` lists the alterations. Deterministic for a given ``seed``.

One file above the project's ~450 lines on purpose: it is one scene's recipe (cameras, objects,
photometry, truth and README), whose steps and the README it writes are read and changed together.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from framework.images import read_exr, srgb_encode
from framework.scene import Camera, Emitter, Mesh, Scene, Segment
from framework.scene.write import write_colmap, write_scene_yaml
from scenes import geometry as g
from scenes import urban_canyon as uc
from scenes.sky import sun_vector

log = logging.getLogger(__name__)

IMAGE, SPP, SEED = 200, 128, 0
SUPERSAMPLE = 2                      # render focal length / largest focal length of the view
REFERENCE_VIEW = "street_002.jpg"
SATURATION = 0.99
JPEG_QUALITY = 95
READ_NOISE = 0.01                    # Gaussian std as a fraction of the view's mean (gained) value
MASK_DILATION = 2                    # pixels (Chebyshev: a 5 x 5 square)
EXPOSURE_RANGE = (0.55, 1.95)        # per-view exposure, drawn log-uniform; gains kept in [0.5, 2]
#: the sky and the sun of urban_canyon, brighter: its surfaces peak at ~0.36 linear radiance, which
#: no gain <= 2 can saturate; at twice the light a gain of ~1.4 clips the sunlit facade
LIGHT_SCALE = 2.0
#: views exposed near the top of the gain range, so that their brightest parts clip
OVEREXPOSED, OVEREXPOSURE_RANGE = ("street_000.jpg", "street_005.jpg", "street_006.jpg"), (1.75, 1.9)
WHITE_BALANCE = 0.05                 # per-channel factors in [1 - 0.05, 1 + 0.05]
CHANNELS = ("R", "G", "B")

#: objects the 3D model lacks: segment name -> (kernels, reference) of their render-only materials
EXTRA_MATERIALS = {
    "car_paint": {"diffuse": [0.05, 0.06, 0.09], "specular": 0.25},    # dark blue paint, mirror coat
    "car_glass": {"diffuse": [0.02, 0.02, 0.025], "specular": 0.45},   # cabin: tinted glass
    "car_tyres": {"diffuse": [0.03, 0.03, 0.03]},
    "pedestrian": {"diffuse": [0.88, 0.82, 0.22]},                     # hi-vis yellow jacket
}
CAR_ORIGIN = (-3.6, 2.7)             # (x, y) of the car's corner: x in [-3.6, 0.6], y in [2.7, 4.5]
PEDESTRIAN_AT = (4.5, 2.1)           # centre of the pedestrian's footprint, in the sun


def car_boxes(origin=CAR_ORIGIN) -> dict[str, list[tuple[list[float], list[float]]]]:
    """The parked car, ~4.2 x 1.8 x 1.5 m, as axis-aligned boxes ``(lo, hi)`` by material;
    ``origin``: (x, y) of its lowest corner."""
    x, y = origin
    body = ([x, y, 0.30], [x + 4.2, y + 1.8, 0.95])
    cabin = ([x + 1.0, y + 0.1, 0.95], [x + 3.3, y + 1.7, 1.50])
    wheels = [([x + x0, y + y0, 0.0], [x + x0 + 0.66, y + y0 + 0.22, 0.62])
              for x0 in (0.45, 3.10) for y0 in (0.0, 1.58)]
    return {"car_paint": [body], "car_glass": [cabin], "car_tyres": wheels}


def pedestrian_box() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The pedestrian, a 0.5 x 0.4 x 1.75 m box whose broad side faces the sun's azimuth:
    ``(origin, ex, ey, ez)`` as :func:`scenes.geometry.box` takes them."""
    sun = sun_vector(uc.SUN_ELEVATION, uc.SUN_AZIMUTH)
    n = np.array([sun[0], sun[1], 0.0]) / np.hypot(sun[0], sun[1])    # horizontal, towards the sun
    u = np.array([-n[1], n[0], 0.0])
    ex, ey, ez = 0.5 * u, -0.4 * n, np.array([0.0, 0.0, 1.75])          # -ey: the face towards the sun
    centre = np.array([*PEDESTRIAN_AT, 0.0])
    return centre - ex / 2 - ey / 2, ex, ey, ez


def extra_meshes(car_origin=CAR_ORIGIN) -> dict[str, g.Mesh]:
    """Material name -> mesh of the objects the model lacks (car at ``car_origin``, pedestrian).
    ``car_origin``: one (x, y), or a sequence of them (a car at each, the same materials)."""
    origins = [car_origin] if np.ndim(car_origin) == 1 else list(car_origin)
    boxes = [car_boxes(o) for o in origins]
    out = {k: g.merge([g.aabox(lo, hi) for b in boxes for lo, hi in b[k]]) for k in boxes[0]}
    out["pedestrian"] = g.box(*pedestrian_box())
    return out


# ----------------------------------------------------------------------------------------------
# Cameras
# ----------------------------------------------------------------------------------------------

def camera_models(views: list[Camera], seed: int = SEED) -> list[tuple[str, list[float]]]:
    """Seeded COLMAP intrinsics (model, params) of each view: ``SIMPLE_RADIAL`` for even
    positions (street_000, 002, ..., aerial_000), ``OPENCV`` with ``fx != fy`` for odd ones.

    The draws do not depend on the image size: focal lengths and principal-point offsets scale
    with the width, distortion coefficients (of normalised coordinates) do not.
    """
    rng = np.random.default_rng((seed, 0))
    out = []
    for i, cam in enumerate(views):
        s = cam.width / IMAGE
        f = cam.f * (1 + rng.uniform(-0.005, 0.005))
        cx, cy = cam.width / 2 + s * rng.uniform(-1.5, 1.5), cam.height / 2 + s * rng.uniform(-1.5, 1.5)
        if i % 2 == 0:
            k = -0.08 + rng.uniform(-0.004, 0.004)
            out.append(("SIMPLE_RADIAL", [round(f, 4), round(cx, 4), round(cy, 4), round(k, 5)]))
        else:
            k1, k2 = -0.10 + rng.uniform(-0.005, 0.005), 0.02 + rng.uniform(-0.002, 0.002)
            p1, p2 = (rng.choice([-1, 1]) * rng.uniform(0.5e-3, 1.5e-3) for _ in range(2))
            out.append(("OPENCV", [round(f * 1.01, 4), round(f / 1.01, 4), round(cx, 4), round(cy, 4),
                                   round(k1, 5), round(k2, 5), round(p1, 6), round(p2, 6)]))
    return out


def _colmap_camera(width: int, height: int, model: str, params):
    """A ``pycolmap.Camera`` of ``model`` with ``params``."""
    import pycolmap
    return pycolmap.Camera(model=model, width=int(width), height=int(height), params=[float(p) for p in params])


def render_camera(view: Camera, model: str, params) -> Camera:
    """The pinhole camera the view is rendered on: same pose, focal length ``SUPERSAMPLE`` times
    the view's largest, principal point at its centre, and large enough that the bilinear
    footprint of every distorted pixel centre lies inside it."""
    distorted = _colmap_camera(view.width, view.height, model, params)
    from framework.scene.undistort import source_pixels
    f = SUPERSAMPLE * max(distorted.focal_length_x, distorted.focal_length_y)
    centred = _colmap_camera(2, 2, "PINHOLE", [f, f, 0.0, 0.0])
    at = source_pixels(source=centred, target=distorted)              # offsets from the centre
    half_w, half_h = (math.ceil(np.abs(at[..., k]).max() + 2) for k in (0, 1))
    return Camera(view.name, 2 * half_w, 2 * half_h, f, float(half_w), float(half_h), view.cam_from_world)


# ----------------------------------------------------------------------------------------------
# Photometry
# ----------------------------------------------------------------------------------------------

def gains(names: list[str], seed: int = SEED) -> dict[str, list[float]]:
    """Seeded per-view, per-channel gains: a log-uniform exposure in ``EXPOSURE_RANGE`` times
    white-balance factors within ±``WHITE_BALANCE``, kept in [0.5, 2]; the ``OVEREXPOSED``
    views' exposure is drawn in ``OVEREXPOSURE_RANGE`` instead;
    exactly 1 for ``REFERENCE_VIEW``."""
    rng = np.random.default_rng((seed, 1))
    out = {}
    for name in names:
        exposure = math.exp(rng.uniform(*np.log(EXPOSURE_RANGE)))
        bright = math.exp(rng.uniform(*np.log(OVEREXPOSURE_RANGE)))
        balance = 1 + rng.uniform(-WHITE_BALANCE, WHITE_BALANCE, 3)
        if name == REFERENCE_VIEW:
            out[name] = [1.0, 1.0, 1.0]
        elif name in OVEREXPOSED:
            out[name] = [round(float(np.clip(bright * b, 0.5, 2.0)), 4) for b in balance]
        else:
            out[name] = [round(float(np.clip(exposure * b, 0.5, 2.0)), 4) for b in balance]
    return out


def sensor_noise(image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Add Gaussian noise of variance ``(READ_NOISE m)^2 (1 + x / m)`` (m: the image mean): a read
    term of 1 % of the mean and a shot term proportional to the value ``x``."""
    m = float(image.mean())
    std = READ_NOISE * m * np.sqrt(1 + np.maximum(image, 0.0) / m)
    return image + rng.normal(0.0, 1.0, image.shape) * std


def encode(linear: np.ndarray) -> tuple[np.ndarray, int]:
    """8-bit sRGB codes of ``linear`` values (clipped to [0, 1]) and the number of pixels with a
    channel clipped at the top."""
    encoded = srgb_encode(linear)
    clipped = int((encoded >= 1.0).any(axis=-1).sum())
    return np.round(np.clip(encoded, 0.0, 1.0) * 255).astype(np.uint8), clipped


def write_jpeg(path: Path, codes: np.ndarray) -> Path:
    """Write 8-bit RGB codes as a JPEG of quality ``JPEG_QUALITY``, 4:4:4 (no chroma subsampling)."""
    from PIL import Image
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(codes, "RGB").save(path, format="JPEG", quality=JPEG_QUALITY, subsampling=0)
    return path


def dilate(mask: np.ndarray, radius: int = MASK_DILATION) -> np.ndarray:
    """Binary dilation of a (H, W) bool mask by a (2r+1) square."""
    h, w = mask.shape
    padded = np.pad(mask, radius)
    out = np.zeros_like(mask)
    for dy in range(2 * radius + 1):
        for dx in range(2 * radius + 1):
            out |= padded[dy:dy + h, dx:dx + w]
    return out


# ----------------------------------------------------------------------------------------------
# The scene rendered for the photographs (the model plus the car and the pedestrian)
# ----------------------------------------------------------------------------------------------

def _reference(value) -> np.ndarray:
    return np.full(3, float(value)) if np.isscalar(value) else np.asarray(value, float)


def photo_scene(folder: Path, segments: list[dict], emitters: list[dict], parts: dict[str, list],
                cameras: list[Camera], car_origin=CAR_ORIGIN, materials: dict | None = None) -> Scene:
    """The in-memory scene the photographs are rendered from: the delivered segments (meshes as
    ``parts`` holds them, emitters as written, the sky read back from ``sky.exr``) plus the
    render-only materials of ``materials`` (default :data:`EXTRA_MATERIALS`, the same keys) on
    :func:`extra_meshes` (the car, or cars, at ``car_origin``)."""
    materials = EXTRA_MATERIALS if materials is None else materials
    segs, meshes = [], []
    for s, seg in enumerate(segments):
        segs.append(Segment(seg["name"], tuple(seg["meshes"]), tuple(seg["kernels"]),
                            {k: _reference(v) for k, v in seg["reference"].items()}))
        for path, (_, (v, f)) in zip(seg["meshes"], parts[seg["name"]]):
            meshes.append(Mesh(path, np.asarray(v, float), np.asarray(f, np.int32), s))
    for name, mesh in extra_meshes(car_origin).items():
        ref = materials[name]
        segs.append(Segment(name, (f"<{name}>",), tuple(ref), {k: _reference(v) for k, v in ref.items()}))
        meshes.append(Mesh(f"<{name}>", np.asarray(mesh[0], float), np.asarray(mesh[1], np.int32), len(segs) - 1))
    ems = []
    for e in emitters:
        if e["type"] == "envmap":
            ems.append(Emitter("envmap", image=read_exr(folder / e["file"]), scale=float(e["scale"]), file=e["file"]))
        else:
            d = np.asarray(e["direction"], float)
            ems.append(Emitter("directional", direction=d / np.linalg.norm(d), irradiance=_reference(e["irradiance"])))
    return Scene(name=folder.name, root=folder, channels=CHANNELS, segments=tuple(segs), meshes=tuple(meshes),
                 emitters=tuple(ems), cameras=tuple(cameras), images=None)


def photographs(scene: Scene, views: list[Camera], models, renders: list[Camera], view_gains: dict, *,
                spp: int, seed: int) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict]:
    """Render, distort, expose, add noise to and encode every view.

    Returns
    -------
    (codes, masks, stats)
        ``codes``: image name -> (H, W, 3) uint8; ``masks``: image name -> (H, W) uint8 (0 on the
        car, dilated); ``stats``: image name -> clip counts, object pixels, render size, seconds.
    """
    from framework.render.backend import set_variant
    from framework.render.mitsuba_scene import MitsubaScene
    from framework.scene.undistort import resample

    set_variant("auto", channels=CHANNELS)
    ms = MitsubaScene(scene, renders, spp=spp, integrator={"type": "path", "max_depth": -1})
    params = scene.parameters()
    ms.set_weights(scene.reference(params), params)
    names = [s.name for s in scene.segments]
    car = [names.index(k) for k in ("car_paint", "car_glass", "car_tyres")]
    walker = names.index("pedestrian")
    noise_rng = np.random.default_rng((seed, 2))
    codes, masks, stats = {}, {}, {}
    for i, (view, (model, p), rcam) in enumerate(zip(views, models, renders)):
        t0 = time.perf_counter()
        source = _colmap_camera(rcam.width, rcam.height, "PINHOLE", [rcam.f, rcam.f, rcam.cx, rcam.cy])
        target = _colmap_camera(view.width, view.height, model, p)
        radiance = ms.render(i, spp=spp, seed=(2 * (seed * 1009 + i) + 1) % (2**31 - 1))
        linear, ok = resample(radiance, source=source, target=target)
        if not ok.all():
            raise RuntimeError(f"{view.name}: the render camera does not cover the distorted view")
        ids = ms.segment_map(i)
        on_car, _ = resample(np.isin(ids, car).astype(float), source=source, target=target)
        on_walker, _ = resample((ids == walker).astype(float), source=source, target=target)
        exposed = linear * np.asarray(view_gains[view.name])
        codes[view.name], clipped = encode(sensor_noise(exposed, noise_rng))
        car_px = dilate(on_car > 0)
        masks[view.name] = np.where(car_px, 0, 255).astype(np.uint8)
        stats[view.name] = {"clipped": clipped, "car": int((on_car > 0).sum()), "masked": int(car_px.sum()),
                            "pedestrian": int((on_walker > 0).sum()), "render": [rcam.width, rcam.height],
                            "seconds": time.perf_counter() - t0}
        log.info("%s: %dx%d render, %d clipped, %.1f s", view.name, rcam.width, rcam.height, clipped,
                 stats[view.name]["seconds"])
    return codes, masks, stats


# ----------------------------------------------------------------------------------------------
# The folder
# ----------------------------------------------------------------------------------------------

def views(image: int = IMAGE) -> list[Camera]:
    """urban_canyon's nine views (8 street, 1 aerial) at ``image`` pixels, named ``*.jpg``."""
    return [replace(c, name=c.name.rsplit(".", 1)[0] + ".jpg") for c in uc.cameras(8, image)]


def _brighter(emitters: list[dict]) -> list[dict]:
    """urban_canyon's emitters with the sky's scale and the sun's irradiance times ``LIGHT_SCALE``."""
    out = []
    for e in emitters:
        e = dict(e)
        if e["type"] == "envmap":
            e["scale"] = float(e.get("scale", 1.0)) * LIGHT_SCALE
        elif e["type"] == "directional":
            e["irradiance"] = [float(v) * LIGHT_SCALE for v in np.atleast_1d(e["irradiance"])]
        out.append(e)
    return out


def build(folder: Path, *, image: int = IMAGE, spp: int = SPP, seed: int = SEED) -> Path:
    """Write the scene folder.

    Parameters
    ----------
    folder : Path
        Output folder (created).
    image : int
        Width and height of the photographs (200 for the bundled scene; the tests use 32).
    spp : int
        Samples per pixel of the (supersampled) pinhole renders.
    seed : int
        Seeds the camera intrinsics, the gains, the sensor noise and Mitsuba's sampler.
    """
    t0 = time.perf_counter()
    folder = Path(folder)
    parts, emitters, segments, cams, models = write_model(folder, image, seed, _comment())
    renders = [render_camera(c, *m) for c, m in zip(cams, models)]
    view_gains = gains([c.name for c in cams], seed)
    codes, masks, stats = photographs(photo_scene(folder, segments, emitters, parts, renders), cams, models,
                                      renders, view_gains, spp=spp, seed=seed)
    write_images(folder, cams, codes, stats, masks)
    truth = _truth(cams, models, view_gains, stats, image=image, spp=spp, seed=seed)
    (folder / "truth.yaml").write_text(_TRUTH_HEAD + yaml.safe_dump(truth, sort_keys=False, width=100,
                                                                     default_flow_style=None))
    (folder / "README.md").write_text(_readme(truth))
    log.info("%s built in %.1f s", folder.name, time.perf_counter() - t0)
    return folder


def write_model(folder: Path, image: int, seed: int, comment: str):
    """Write the model: meshes, ``sky.exr``, the distorted COLMAP cameras and ``scene.yaml``
    (urban_canyon's segments under :func:`_brighter` light, field photometry).

    Returns
    -------
    (parts, emitters, segments, cams, models)
        :func:`scenes.urban_canyon.meshes`, scene.yaml's emitters and segments, the views
        (:func:`views`) and their COLMAP intrinsics (:func:`camera_models`).
    """
    parts = uc.meshes()
    files = {seg: uc.write_mesh_files(folder, p) for seg, p in parts.items()}
    emitters = _brighter(uc.write_lighting(folder, "rgb"))
    segments = uc.segments("rgb", files)
    cams = views(image)
    models = camera_models(cams, seed)
    write_colmap(folder / "sparse", cams, uc.landmarks(), models=models)
    photometry = {"encoding": "srgb", "exposure": "per_view", "reference_view": REFERENCE_VIEW,
                  "saturation": SATURATION}
    write_scene_yaml(folder / "scene.yaml", {"name": folder.name, "channels": "rgb", "segments": segments,
                                             "emitters": emitters, "photometry": photometry}, comment)
    return parts, emitters, segments, cams, models


def write_images(folder: Path, cams: list[Camera], codes: dict, stats: dict, masks: dict | None = None) -> None:
    """Write ``images/<view>`` (JPEG) and, where given, ``masks/<view>.png``; adds each view's
    ``saturated`` count (decoded pixels with a channel >= ``SATURATION`` x 255) to ``stats``."""
    from PIL import Image
    for c in cams:
        path = write_jpeg(folder / "images" / c.name, codes[c.name])
        if masks is not None:
            (folder / "masks").mkdir(exist_ok=True)
            Image.fromarray(masks[c.name], "L").save(folder / "masks" / f"{c.name}.png", format="PNG")
        decoded = np.asarray(Image.open(path).convert("RGB"))
        stats[c.name]["saturated"] = int((decoded >= SATURATION * 255).any(axis=-1).sum())


def _truth(cams, models, view_gains, stats, *, image, spp, seed) -> dict:
    ped = pedestrian_box()
    return {
        "seed": seed,
        "image_size": [image, image],
        "reference_view": REFERENCE_VIEW,
        "gains": {c.name: view_gains[c.name] for c in cams},
        "cameras": {c.name: {"model": m, "params": [float(x) for x in p]} for c, (m, p) in zip(cams, models)},
        "render": {"integrator": "path, max_depth -1 (unbounded)", "spp": spp,
                   "supersample": SUPERSAMPLE, "resampling": "bilinear at the distorted pixel centres, no box average",
                   "sizes": {c.name: stats[c.name]["render"] for c in cams}},
        "noise": {"read_std_fraction_of_mean": READ_NOISE,
                  "model": "x + N(0, (0.01 m)^2 (1 + x/m)), m = mean of the gained view, before encoding"},
        "encoding": {"transfer": "srgb", "bits": 8, "jpeg_quality": JPEG_QUALITY, "chroma_subsampling": "4:4:4",
                     "saturation": SATURATION},
        "clipped_pixels": {c.name: stats[c.name]["clipped"] for c in cams},
        "saturated_pixels": {c.name: stats[c.name]["saturated"] for c in cams},
        "objects": {
            "car": {"masked": True, "mask_dilation_px": MASK_DILATION, "size_m": [4.2, 1.8, 1.5],
                    "boxes": {k: [{"lo": _rounded(lo), "hi": _rounded(hi)} for lo, hi in b]
                              for k, b in car_boxes().items()},
                    "materials": {k: EXTRA_MATERIALS[k] for k in ("car_paint", "car_glass", "car_tyres")},
                    "pixels": {c.name: stats[c.name]["car"] for c in cams},
                    "masked_pixels": {c.name: stats[c.name]["masked"] for c in cams}},
            "pedestrian": {"masked": False, "size_m": [0.5, 0.4, 1.75],
                           "box": {k: _rounded(v) for k, v in zip(("origin", "ex", "ey", "ez"), ped)},
                           "material": EXTRA_MATERIALS["pedestrian"],
                           "pixels": {c.name: stats[c.name]["pedestrian"] for c in cams}},
        },
    }


def _rounded(values) -> list[float]:
    return [round(float(x), 6) for x in values]


_TRUTH_HEAD = """\
# Ground truth of the field alterations, for evaluation only (the scene loader ignores this file).
# gains: pixel = gain[view][channel] * radiance before noise and encoding; the reference view's are 1.
# clipped_pixels: pixels with a channel >= 1 after sRGB encoding (before 8-bit quantisation);
# saturated_pixels: pixels of the decoded JPEG with a channel >= saturation * 255.
"""


def _comment() -> str:
    return f"""Generated by `python -m scenes.build urban_canyon_field` (scenes/urban_canyon_field.py); do not edit.
urban_canyon (same meshes, segments, references, sky and sun, same 9 view poses) as field photographs:
distorted COLMAP cameras (SIMPLE_RADIAL / OPENCV), 8-bit sRGB JPEG (quality {JPEG_QUALITY}, 4:4:4), unknown
per-view per-channel gains (reference view {REFERENCE_VIEW}: gains 1), sensor noise, clipped highlights,
and a parked car (masked in masks/) and a pedestrian (not masked) that the model lacks.
The true gains and the alterations are in truth.yaml and README.md."""


def _readme(t: dict) -> str:
    rows = []
    for name, cam in t["cameras"].items():
        params = ", ".join(f"{x:g}" for x in cam["params"])
        gain = ", ".join(f"{x:.4f}" for x in t["gains"][name])
        car, ped = t["objects"]["car"], t["objects"]["pedestrian"]
        rows.append(f"| {name} | {cam['model']} | {params} | {gain} | {t['clipped_pixels'][name]} | "
                    f"{t['saturated_pixels'][name]} | {car['pixels'][name]} / {car['masked_pixels'][name]} | "
                    f"{ped['pixels'][name]} |")
    size = t["image_size"][0]
    car = t["objects"]["car"]
    return f"""# urban_canyon_field

Generated by `python -m scenes.build urban_canyon_field` (`scenes/urban_canyon_field.py`, seed
{t['seed']}); do not edit by hand. The street canyon of `urban_canyon` — the same meshes, segments,
references, sky (`sky.exr`) and sun, and the same nine view poses — delivered as a mobile-mapping
camera would deliver it. `scene.yaml` lists only the model (no car, no pedestrian) and adds
`photometry: {{encoding: srgb, exposure: per_view, reference_view: {t['reference_view']}, saturation: {SATURATION}}}`.
`truth.yaml` holds every true value below in machine-readable form.

## What was done to the photographs

1. **Cameras** (`sparse/cameras.txt`): {size}x{size} px; even street views and the aerial view
   `SIMPLE_RADIAL` (f, cx, cy, k; k about -0.08), odd street views `OPENCV` (fx, fy, cx, cy, k1, k2,
   p1, p2; fx/fy = 1.0201, k1 about -0.1, k2 about 0.02, |p1|, |p2| in [0.5, 1.5]e-3). Principal points
   within 1.5 px (at 200 px) of the centre. Poses as in `urban_canyon` (images renamed `*.jpg`).
2. **Rendering**: Mitsuba `path`, unbounded depth, {t['render']['spp']} spp, at the segments' reference
   weights, on a `PINHOLE` camera of the same pose with focal length {SUPERSAMPLE}x the view's largest
   (fx, fy) and a size covering every distorted pixel's ray (render sizes in `truth.yaml`); then
   resampled onto the distorted camera with `framework.scene.undistort.resample` (bilinear at the
   distorted pixel centres, in linear float64; no box average: at 2x the bilinear footprint is
   about one output pixel).
3. **Objects the model lacks** (rendered into the photographs only):
   - a parked car, {car['size_m'][0]} x {car['size_m'][1]} x {car['size_m'][2]} m, on the asphalt at the north curb
     (x in [-3.6, 0.6], y in [2.7, 4.5]): body box of dark blue paint (diffuse [0.05, 0.06, 0.09] +
     mirror 0.25), cabin box of tinted glass (diffuse 0.02 + mirror 0.45), four tyre boxes
     (diffuse 0.03). **Masked**: `masks/<image name>.png` is 0 on the car's pixels (the car seen
     through the pixel centres of the render camera, resampled to the distorted geometry, any
     car weight > 0, dilated by {MASK_DILATION} px with a 5x5 square), 255 elsewhere.
   - a pedestrian, 0.5 x 0.4 x 1.75 m box at (4.5, 2.1) on the sunlit side of the street, its broad
     side facing the sun, hi-vis clothing (diffuse [0.88, 0.82, 0.22]). **Not masked.**
4. **Exposure**: per-view, per-channel gains g = exposure x white balance, exposure log-uniform in
   [{EXPOSURE_RANGE[0]}, {EXPOSURE_RANGE[1]}], white-balance factors in [{1 - WHITE_BALANCE:g}, {1 + WHITE_BALANCE:g}] per channel, gains kept in
   [0.5, 2]; `{t['reference_view']}` has gains exactly 1. pixel = g_v,c x radiance.
   Three views are exposed near the top of that range: {', '.join(f'`{v}`' for v in OVEREXPOSED)}, exposure
   log-uniform in [{OVEREXPOSURE_RANGE[0]}, {OVEREXPOSURE_RANGE[1]}], so that their brightest parts clip.
   The light is urban_canyon's sky and sun times {LIGHT_SCALE} (scene.yaml says so: the envmap's `scale`
   and the sun's `irradiance`): at urban_canyon's own light the surfaces peak at about 0.36 linear
   radiance, which no gain <= 2 saturates.
5. **Sensor noise**: Gaussian, variance (0.01 m)^2 (1 + x / m) (m: mean of the exposed view,
   x: the pixel value): a read term of 1 % of the mean plus a shot term; then no clamping
   until the encoding.
6. **Encoding**: sRGB transfer (`framework.images.srgb_encode`), clipped to [0, 1], quantised
   to 8 bits, JPEG quality {JPEG_QUALITY} with 4:4:4 chroma (Pillow, `subsampling=0`).

## Per view

Clipped: pixels with a channel >= 1 after encoding (before quantisation). Saturated: pixels of
the decoded JPEG with a channel >= {SATURATION} x 255 (what the loader ignores). Car: pixels on
the car / masked (dilated). Pedestrian: pixels on the pedestrian (not masked).

| view | model | params | gains (R, G, B) | clipped | saturated | car / masked | pedestrian |
|---|---|---|---|---|---|---|---|
{chr(10).join(rows)}
"""
