"""``urban_canyon_survey``: :mod:`scenes.urban_canyon` as a survey photographs it.

Same meshes, segments, references and nine views as ``urban_canyon``, plus a calibration panel,
and three things a survey does not know exactly, each declared as an unknown in ``scene.yaml``:

* **The light's intensity.** The light is a ``sunsky`` emitter placed by place and time (Paris,
  :data:`LATITUDE`, :data:`LONGITUDE`, :data:`TIME`: the sun at elevation 44.9°, compass azimuth
  245.6°, close to urban_canyon's 45° / 245°; turbidity 3, ground albedo 0.2), declared with
  ``sun_scale: unknown, sky_scale: unknown``. The photographs were taken under a sun
  :data:`TRUE_SUN` times and a sky :data:`TRUE_SKY` times that nominal light (12 % brighter,
  10 % dimmer).
* **The lens.** Every view is taken through one lens (one COLMAP camera, id 1, shared by the nine
  views, whose intrinsics are identical) with a falloff pixel = (1 - 0.3 r²) · radiance
  (:data:`PROFILE`; r = distance of the pixel centre from the principal point / half the image
  diagonal, as :func:`methods.symbolic.survey.vignetting.pixel_radius` defines it, so the corners get
  70 %); declared ``photometry: {vignetting: estimate}``.
* **The calibration panel.** A 1 m x 1 m grey panel (diffuse :data:`PANEL_DIFFUSE`), its own
  segment ``panel`` with ``known: {diffuse: 0.5}``, lies on the asphalt in the sunlit part of
  the street, :data:`PANEL_HEIGHT` above the road (so the two surfaces never z-fight), seen by
  the aerial view and several street views (the pixel counts are in ``truth.yaml``).

A second hour: two more photographs (:data:`MORNING_POSES`, the poses of a street view facing each
facade, the same lens and size) were taken the same day at :data:`MORNING_TIME` (the
sun at elevation 16.8°, compass azimuth 79.0°: north of east, low along the street, it lights the
south facade, in shade all afternoon, and leaves the north facade, sunlit in the afternoon, in
shade), scene.yaml's light :data:`MORNING` (``lights``).
That light is declared known (scales 1, as if measured on site) and the morning photographs are
rendered under it exactly: a fit on the afternoon's views predicts them (``holdout=[...]``,
relighting) against a floor that is the truth.

The photographs ``images/<view>.exr`` are linear radiance: Mitsuba ``path`` (unbounded depth)
at the reference weights (the panel at its known value) under the true light, :data:`SPP` samples
per pixel, times the falloff, written as half-float EXR. ``README.md`` in the folder says what
differs from the model; ``truth.yaml`` holds the true values (the loader ignores both).
Deterministic for a given ``seed`` on one machine (each view is one Mitsuba render of its own
seed).
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import yaml

from framework.scene.write import write_colmap, write_scene_yaml
from scenes import geometry as g
from scenes import urban_canyon as uc
from scenes.urban_canyon_glossy import write_half_exr

LATITUDE, LONGITUDE, TIME = 48.8566, 2.3522, "2026-05-19T16:40:00+02:00"
TURBIDITY, GROUND_ALBEDO = 3.0, 0.2
TRUE_SUN, TRUE_SKY = 1.12, 0.90              # true light / declared light
PROFILE = (-0.3, 0.0, 0.0)                   # pixel = (1 + a1 r² + a2 r⁴ + a3 r⁶) · radiance
PANEL_NAME, PANEL_DIFFUSE = "panel", 0.5
PANEL_CENTRE, PANEL_SIZE, PANEL_HEIGHT = (2.0, 3.0), 1.0, 0.01     # (x, y), metres
IMAGE, SPP, SEED = uc.IMAGE, 1024, 0
MORNING, MORNING_TIME = "morning", "2026-05-19T08:00:00+02:00"
#: the morning's photographs: name -> the afternoon view whose pose it takes
MORNING_POSES = {"morning_street_002.png": "street_002.png", "morning_street_005.png": "street_005.png"}
#: view i of the morning (in name order) is rendered with seed 2 (1009 seed + MORNING_SEEDS + i) + 1
MORNING_SEEDS = 100


def panel_mesh() -> g.Mesh:
    """The calibration panel: a horizontal ``PANEL_SIZE`` square at ``PANEL_HEIGHT``, facing up."""
    x, y = PANEL_CENTRE
    h = PANEL_SIZE / 2
    return g.quad([x - h, y - h, PANEL_HEIGHT], [PANEL_SIZE, 0, 0], [0, PANEL_SIZE, 0])


def sunsky(*, turbidity: float = TURBIDITY, sun_scale="unknown", sky_scale="unknown", time: str = TIME) -> dict:
    """The scene.yaml ``sunsky`` emitter at :data:`LATITUDE`, :data:`LONGITUDE`, ``time``
    (default :data:`TIME`); a scale of None is left out (1, known)."""
    scales = {k: v for k, v in (("sun_scale", sun_scale), ("sky_scale", sky_scale)) if v is not None}
    return {"type": "sunsky", "latitude": LATITUDE, "longitude": LONGITUDE, "time": time,
            "turbidity": float(turbidity), "ground_albedo": GROUND_ALBEDO, **scales}


def morning_light() -> dict:
    """scene.yaml ``lights``' entry of the morning: its views and its sunsky at
    :data:`MORNING_TIME`, scales known (1)."""
    return {"name": MORNING, "views": sorted(MORNING_POSES),
            "emitters": [sunsky(time=MORNING_TIME, sun_scale=None, sky_scale=None)]}


def cameras(image: int = IMAGE) -> list:
    """urban_canyon's nine views, then the morning's (:data:`MORNING_POSES`), ``image`` pixels wide."""
    afternoon = uc.cameras(8, image)
    by_name = {c.name: c for c in afternoon}
    return afternoon + [dataclasses.replace(by_name[pose], name=name) for name, pose in sorted(MORNING_POSES.items())]


def segments(files: dict[str, list[str]], *, panel_known: bool = True) -> list[dict]:
    """urban_canyon's rgb segments and the panel: ``known: {diffuse: PANEL_DIFFUSE}``, or with
    ``panel_known=False`` an ordinary segment whose ``reference`` is that value."""
    panel = {"name": PANEL_NAME, "meshes": files[PANEL_NAME], "kernels": ["diffuse"]}
    panel["known" if panel_known else "reference"] = {"diffuse": PANEL_DIFFUSE}
    return uc.segments("rgb", {k: v for k, v in files.items() if k != PANEL_NAME}) + [panel]


def pixel_radius(width: int, height: int, cx: float, cy: float) -> np.ndarray:
    """``(height, width)`` r of each pixel centre: its distance from the principal point
    ``(cx, cy)`` over half the image diagonal (1 at the corners of a centred camera)."""
    xs, ys = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    return np.hypot(xs - cx, ys - cy) / (0.5 * np.hypot(width, height))


def falloff(r: np.ndarray, profile=PROFILE) -> np.ndarray:
    """``1 + a1 r² + a2 r⁴ + a3 r⁶`` for ``profile = (a1, a2, a3)``."""
    a1, a2, a3 = profile
    r2 = np.asarray(r, float) ** 2
    return 1.0 + r2 * (a1 + r2 * (a2 + r2 * a3))


def true_light(scene, *, sun: float = TRUE_SUN, sky: float = TRUE_SKY, turbidity: float | None = None):
    """``scene`` (loaded from a folder whose only emitter is one ``sunsky``) under the light of the
    photographs: its sky times ``sky``, its sun times ``sun``, both known (not unknown scales).

    ``turbidity``: bake the sky and the sun again at this turbidity (same sun direction, same
    ground albedo); default the declared one.
    """
    from framework.render.sunsky import sunsky_parts

    sky_e, sun_e = scene.emitters
    if (sky_e.part, sun_e.part) != ("sky", "sun"):
        raise ValueError(f"{scene.name}: expected one sunsky emitter (its sky and its sun)")
    image, irradiance = sky_e.image, sun_e.irradiance
    if turbidity is not None:
        image, irradiance = sunsky_parts(-np.asarray(sun_e.direction), "rgb", turbidity=turbidity,
                                         ground_albedo=GROUND_ALBEDO, size=image.shape[:2])
    return dataclasses.replace(scene, emitters=(
        dataclasses.replace(sky_e, image=image, scale=sky, scale_unknown=False),
        dataclasses.replace(sun_e, irradiance=np.asarray(irradiance) * sun, scale_unknown=False)))


def render_photographs(scene, out: Path, *, spp: int, seed: int, profile=PROFILE, first: int = 0) -> dict[str, dict]:
    """Path trace the views of ``scene`` photographed under its light (a loaded
    :class:`~framework.scene.Scene`, the light as it should be: :meth:`~framework.scene.Scene.lit_by`
    its ``light``) at its reference weights, times the falloff of ``profile``, into
    ``out/<view stem>.exr`` (half float); view i (in name order) with seed
    ``2 (1009 seed + first + i) + 1``.

    Returns
    -------
    dict
        View name -> ``{"seconds": render time, "panel_pixels": pixels whose centre sees the panel}``.
    """
    from framework.render.backend import set_variant
    from framework.render.mitsuba_scene import MitsubaScene

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    set_variant("auto", channels=scene.channels)
    cams = scene.lit_by(scene.light)
    ms = MitsubaScene(scene, cams, spp=spp, integrator={"type": "path", "max_depth": -1})
    params = scene.parameters()
    ms.set_weights(scene.reference(params), params)
    panel = [s.name for s in scene.segments].index(PANEL_NAME)
    stats = {}
    for i, cam in enumerate(cams):
        t0 = time.perf_counter()
        radiance = ms.render(i, spp=spp, seed=2 * (seed * 1009 + first + i) + 1)
        factor = falloff(pixel_radius(cam.width, cam.height, cam.cx, cam.cy), profile)
        write_half_exr(out / f"{Path(cam.name).stem}.exr", radiance * factor[..., None])
        stats[cam.name] = {"seconds": time.perf_counter() - t0,
                           "panel_pixels": int((ms.segment_map(i) == panel).sum())}
    return stats


def scene_yaml(name: str, files: dict[str, list[str]]) -> dict:
    """The bundled scene.yaml: urban_canyon's segments, the known panel, the nominal sunsky with
    both scales unknown, the morning's light, the vignetting estimated."""
    return {"name": name, "channels": "rgb", "segments": segments(files), "emitters": [sunsky()],
            "lights": [morning_light()], "photometry": {"vignetting": "estimate"}}


def build(folder: Path, *, image: int = IMAGE, spp: int = SPP, seed: int = SEED) -> Path:
    """Write the scene folder: the model (scene.yaml, meshes, one shared COLMAP camera), the
    photographs under the true light through the lens, ``truth.yaml`` and ``README.md``.

    Parameters
    ----------
    folder : Path
        Output folder (created).
    image : int
        Width and height of the views (200 for the bundled scene; tests may use fewer).
    spp : int
        Samples per pixel of the photographs.
    seed : int
        Seeds Mitsuba's sampler (view i uses ``2 (1009 seed + i) + 1``).
    """
    from framework.scene import load_scene

    folder = Path(folder)
    parts = {**uc.meshes(), PANEL_NAME: [(PANEL_NAME, panel_mesh())]}
    files = {seg: uc.write_mesh_files(folder, p) for seg, p in parts.items()}
    write_colmap(folder / "sparse", cameras(image), uc.landmarks(), shared_camera=True)
    write_scene_yaml(folder / "scene.yaml", scene_yaml(folder.name, files), _comment(spp, seed))
    loaded = load_scene(folder)                      # before images/ exists: no photographs yet
    scene = true_light(loaded)
    stats = render_photographs(scene, folder / "images", spp=spp, seed=seed)
    morning = loaded.under(MORNING)                  # declared known: the photographs' light
    stats.update(render_photographs(morning, folder / "images", spp=spp, seed=seed, first=MORNING_SEEDS))
    truth = _truth(scene, stats, image=image, spp=spp, seed=seed, morning=morning)
    (folder / "truth.yaml").write_text(_TRUTH_HEAD + yaml.safe_dump(truth, sort_keys=False, width=100,
                                                                     default_flow_style=None))
    (folder / "README.md").write_text(_readme(truth))
    return folder


def _truth(scene, stats: dict, *, image: int, spp: int, seed: int, morning) -> dict:
    return {"seed": seed, "image_size": [image, image],
            "light": {"sun_scale": TRUE_SUN, "sky_scale": TRUE_SKY, "turbidity": TURBIDITY,
                      "sun_direction": [round(float(x), 6) for x in -np.asarray(scene.emitters[1].direction)]},
            "morning": {"light": MORNING, "time": MORNING_TIME, "views": dict(sorted(MORNING_POSES.items())),
                        "sun_scale": 1.0, "sky_scale": 1.0, "turbidity": TURBIDITY,
                        "sun_direction": [round(float(x), 6) for x in -np.asarray(morning.emitters[1].direction)]},
            "vignetting": {"camera": 1, "profile": list(PROFILE), "corner": float(falloff(1.0))},
            "panel": {"segment": PANEL_NAME, "diffuse": PANEL_DIFFUSE, "centre": list(PANEL_CENTRE),
                      "size_m": PANEL_SIZE, "height_m": PANEL_HEIGHT,
                      "pixels": {name: s["panel_pixels"] for name, s in stats.items()}},
            "render": {"integrator": "path, max_depth -1 (unbounded)", "spp": spp,
                       "seeds": f"view i (in name order) of the afternoon: 2 (1009 seed + i) + 1, of the morning: "
                                f"2 (1009 seed + {MORNING_SEEDS} + i) + 1", "encoding": "half-float EXR"}}


_TRUTH_HEAD = """\
# Ground truth of the survey scene, for evaluation only (the scene loader ignores this file).
# light: the afternoon photographs' sun and sky are these times the sunsky scene.yaml declares.
# morning: the morning photographs' light is the one scene.yaml's lights declare for them, as declared.
# vignetting: pixel = (1 + a1 r^2 + a2 r^4 + a3 r^6) * radiance, r = distance from the principal point / half diagonal.
# panel pixels: pixels of each view whose centre sees the panel.
"""


def _comment(spp: int, seed: int) -> str:
    return f"""Generated by `python -m scenes.build urban_canyon_survey` (scenes/urban_canyon_survey.py); do not
edit by hand. urban_canyon (same meshes, segments, references and views) with a 1 m calibration
panel (known diffuse {PANEL_DIFFUSE}), the light a sunsky by place and time with unknown sun and sky scales,
and the lens's vignetting estimated (one COLMAP camera for the eleven views). Two views of the
same day's morning ({MORNING_TIME[11:16]}) are lit by the light {MORNING} (lights), known.
images/: Mitsuba path, unbounded depth, {spp} spp, seed {seed}, under a sun x{TRUE_SUN} and a sky x{TRUE_SKY}
of this sunsky (the morning's under its light as declared), times the falloff 1 - 0.3 r^2 (README.md,
truth.yaml)."""


def _readme(t: dict) -> str:
    rows = "\n".join(f"| {name} | {n} |" for name, n in t["panel"]["pixels"].items())
    size = t["image_size"][0]
    return f"""# urban_canyon_survey

Generated by `python -m scenes.build urban_canyon_survey` (`scenes/urban_canyon_survey.py`, seed
{t['seed']}); do not edit by hand. The street canyon of `urban_canyon` (the same meshes, segments,
references and nine {size}x{size} views) as a survey photographs it, and two more photographs of the
same street in the morning. `truth.yaml` holds the true values below in machine-readable form (the
loader ignores it).

## What the model declares (`scene.yaml`)

- The light: one `sunsky` emitter at latitude {LATITUDE}, longitude {LONGITUDE}, `{TIME}`
  (the sun at elevation 44.9 deg, compass azimuth 245.6 deg; urban_canyon's is at 45 / 245),
  turbidity {TURBIDITY:g}, ground albedo {GROUND_ALBEDO}, north +y, with `sun_scale: unknown` and
  `sky_scale: unknown`: its shape is known, its intensity is not.
- A second light, `lights: [{{name: {MORNING}, ...}}]`: the photographs
  {', '.join(f'`{v}`' for v in sorted(MORNING_POSES))} (the poses of
  {', '.join(f'`{p}`' for _, p in sorted(MORNING_POSES.items()))}) were taken at `{MORNING_TIME}`, under the
  same sunsky at that time (the sun at elevation 16.8 deg, compass azimuth 79.0 deg: low and north of east,
  it lights the south facade, in shade all afternoon, and leaves the north facade in shade), declared known
  (scales 1). `views=all` selects the nine afternoon views; a fit on them
  predicts the morning's photographs when they are held out (`holdout=[...]`: relighting).
- `photometry: {{vignetting: estimate}}`: one lens falloff 1 + a1 r^2 + a2 r^4 + a3 r^6 to estimate
  for COLMAP camera 1, which all eleven views share (their intrinsics are identical).
- A segment `{PANEL_NAME}`: a {PANEL_SIZE:g} m x {PANEL_SIZE:g} m calibration panel on the asphalt, centred at
  (x, y) = ({PANEL_CENTRE[0]:g}, {PANEL_CENTRE[1]:g}) in the sunlit part of the street, {PANEL_HEIGHT} m above the road
  (`meshes/{PANEL_NAME}.ply`), kernel `diffuse` with `known: {{diffuse: {PANEL_DIFFUSE}}}`.
- Every other segment: urban_canyon's kernels and references.

## How the photographs differ from the model

1. **Light**: in the afternoon the sun is {TRUE_SUN} times and the sky {TRUE_SKY} times the declared sunsky
   (12 % brighter sun, 10 % dimmer sky; the sky's map below the horizon is scaled with the sky). The
   morning's photographs are rendered under the morning light as declared.
2. **Lens**: pixel = (1 - 0.3 r^2) x radiance (a1 = -0.3, a2 = a3 = 0), r = distance of the pixel
   centre from the principal point over half the image diagonal: 70 % at the corners (`corner` = 0.7).
3. **Rendering**: Mitsuba `path`, unbounded depth, {t['render']['spp']} spp, at the references (the panel at
   its known {PANEL_DIFFUSE}), one render per view of seed 2 (1009 seed + i) + 1 (i: the view's index in name
   order among the afternoon's views; 2 (1009 seed + {MORNING_SEEDS} + i) + 1 among the morning's); linear
   radiance in Mitsuba sunsky's unit, half-float EXR (`images/<view>.exr`).

## Panel pixels per view

| view | pixels seeing the panel |
|---|---|
{rows}
"""
