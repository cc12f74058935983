"""``urban_canyon_misfit``: :mod:`scenes.urban_canyon_field`'s photographs with what a survey's
model lacks, in the photographs only.

The model (``scene.yaml``, meshes, the distorted COLMAP cameras and their poses) is
urban_canyon_field's; the photographs are made by the same steps (cameras, distortion, gains,
sensor noise, sRGB JPEG: :func:`scenes.urban_canyon_field.photographs`) from a truth that differs:

- **the parked car is not masked** (no ``masks/``) and stands at :data:`CAR_ORIGIN`, at the south
  curb, where it covers 30-60 % of the asphalt's pixels in two street views (street_001 and
  street_005) and under 10 % in the others (measured by :func:`car_shares`; the pedestrian
  stays, unmasked, as in urban_canyon_field);
- **every view's true pose is rotated** from the pose the COLMAP model holds by 0.5-1 px
  (:func:`pose_offsets`: a rotation about a random axis of the camera frame, angle = px / f);
- **the north facade stands 0.1 m behind its mesh** (:data:`FACADE_SHIFT`: the north building's
  meshes translated along the facade's inward normal, +y);
- **the walls are textured**: the ``wall`` segment's meshes cut into :data:`TILE` m tiles (a grid
  of world-axis cells, :func:`tile_pieces`) whose diffuse weight is the reference times 1 + δ,
  δ one of :data:`LEVELS` values in ±:data:`TILE_RANGE` per tile (seeded), the area-weighted mean
  of δ 0 (:func:`tile_levels`), so scene.yaml's reference stays the truth.

``truth.yaml`` holds the measured values (car shares, pose offsets, facade displacement, tile
statistics, gains); ``README.md`` beside the scene says what differs and by how much.
Deterministic for a given ``seed``.
"""
from __future__ import annotations

import logging
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from framework.scene import Camera
from scenes import geometry as g
from scenes import urban_canyon as uc
from scenes import urban_canyon_field as field

log = logging.getLogger(__name__)

IMAGE, SPP, SEED = field.IMAGE, field.SPP, field.SEED
#: the car's lowest corner (x, y): x in [-5.75, -1.55], y in [-4.4, -2.6], 0.1 m from the south kerb
CAR_ORIGIN = (-5.75, -4.4)
CAR = ("car_paint", "car_glass", "car_tyres")
SHARE_RANGE = (0.3, 0.6)                 # the car's share of the asphalt's pixels in its two views
POSE_PX = (0.5, 1.0)                     # rotation of each view's true pose, in pixels (angle x f)
FACADE_SIDE, FACADE_SHIFT = 1, 0.1       # the north building, 0.1 m behind its mesh (+y)
TILE, TILE_RANGE, LEVELS = 0.5, 0.2, 9   # tile size (m), diffuse ±20 %, in 9 levels
WALL = "wall"


# ----------------------------------------------------------------------------------------------
# Poses
# ----------------------------------------------------------------------------------------------

def rotation(axis, angle: float) -> np.ndarray:
    """The (3, 3) rotation by ``angle`` (radians) about the unit ``axis`` (Rodrigues)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def pose_offsets(cams: list[Camera], seed: int = SEED) -> dict[str, dict]:
    """Seeded offset of each view's true pose: a unit ``axis`` of the camera frame (uniform on the
    sphere), ``px`` uniform in :data:`POSE_PX` (pixels of the view, whatever its size) and
    ``angle = px / f``. The axis and px do not depend on the image size."""
    rng = np.random.default_rng((seed, 3))
    out = {}
    for cam in cams:
        axis = rng.normal(size=3)
        px = rng.uniform(*POSE_PX)
        out[cam.name] = {"axis": axis / np.linalg.norm(axis), "px": px, "angle": px / cam.f}
    return out


def rotated(cam: Camera, offset: dict) -> Camera:
    """``cam`` with its pose rotated about its own centre by ``offset`` (:func:`pose_offsets`):
    a point at camera coordinates p in ``cam`` is at Q p in the result."""
    q = rotation(offset["axis"], offset["angle"])
    pose = cam.cam_from_world
    return replace(cam, cam_from_world=np.concatenate([q @ pose[:, :3], (q @ pose[:, 3])[:, None]], axis=1))


def image_motion(cam: Camera, offset: dict) -> dict[str, float]:
    """How far the rotation moves the image, in pixels: at the principal point (``centre``, and
    ``centre_shift`` [dx, dy]: where the photograph shows what the COLMAP camera shows at the
    principal point, minus the principal point), RMS and largest over the pixel centres."""
    q = rotation(offset["axis"], offset["angle"])
    xs, ys = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    d = np.stack([(xs - cam.cx) / cam.f, (ys - cam.cy) / cam.f, np.ones_like(xs)], -1).reshape(-1, 3)
    d = np.vstack([[0.0, 0.0, 1.0], d])
    moved = d @ q.T
    delta = cam.f * (moved[:, :2] / moved[:, 2:] - d[:, :2])
    shift = np.linalg.norm(delta, axis=1)
    return {"centre": float(shift[0]), "centre_shift": [float(x) for x in delta[0]],
            "rms": float(np.sqrt(np.mean(shift[1:] ** 2))), "max": float(shift[1:].max())}


# ----------------------------------------------------------------------------------------------
# Textured walls
# ----------------------------------------------------------------------------------------------

def _split(poly: np.ndarray, axis: int, value: float) -> tuple[np.ndarray, np.ndarray]:
    """(part at or below ``value``, part at or above it) along ``axis`` of a convex polygon (k, 3)."""
    d = poly[:, axis] - value
    lo, hi = [], []
    for i in range(len(poly)):
        j = (i + 1) % len(poly)
        if d[i] <= 0:
            lo.append(poly[i])
        if d[i] >= 0:
            hi.append(poly[i])
        if d[i] * d[j] < 0:
            cut = poly[i] + (poly[j] - poly[i]) * (d[i] / (d[i] - d[j]))
            lo.append(cut)
            hi.append(cut)
    return np.array(lo), np.array(hi)


def _area(poly: np.ndarray) -> float:
    return 0.5 * float(np.linalg.norm(np.cross(poly[1:-1] - poly[0], poly[2:] - poly[0]).sum(0)))


def tile_pieces(mesh: g.Mesh, size: float = TILE) -> list[tuple[tuple[int, int, int], np.ndarray]]:
    """The triangles of ``mesh`` cut along the planes x, y, z = k ``size``: ``(cell, polygon)``
    per piece (convex, the triangle's winding), ``cell`` the grid cell holding it."""
    out = []
    for tri in mesh[0][mesh[1]]:
        polys = [tri]
        for axis in range(3):
            lo, hi = tri[:, axis].min(), tri[:, axis].max()
            cuts = np.arange(np.floor(lo / size) + 1, np.ceil(hi / size)) * size
            cuts = cuts[(cuts > lo + 1e-9) & (cuts < hi - 1e-9)]
            polys = [piece for poly in polys for piece in _cut(poly, axis, cuts)]
        out += [(tuple(np.floor(p.mean(0) / size).astype(int).tolist()), p) for p in polys if _area(p) > 1e-12]
    return out


def _cut(poly: np.ndarray, axis: int, cuts: np.ndarray) -> list[np.ndarray]:
    out = []
    for c in cuts:
        below, poly = _split(poly, axis, c)
        if len(below) >= 3:
            out.append(below)
        if len(poly) < 3:
            return out
    return out + [poly]


def _fan(polys: list[np.ndarray]) -> g.Mesh:
    """One mesh of convex polygons, each as a triangle fan."""
    return g.merge([(p, np.array([[0, k, k + 1] for k in range(1, len(p) - 1)])) for p in polys])


def tile_levels(areas: np.ndarray, seed: int = SEED) -> tuple[np.ndarray, np.ndarray]:
    """``(level of each tile, δ of each level)``: levels drawn uniformly (seeded), the :data:`LEVELS`
    values evenly spaced, shifted so that the area-weighted mean of δ is 0 and scaled so that the
    largest |δ| is :data:`TILE_RANGE`."""
    rng = np.random.default_rng((seed, 4))
    level = rng.integers(0, LEVELS, len(areas))
    u = np.linspace(-1.0, 1.0, LEVELS)
    u = u - np.sum(areas * u[level]) / areas.sum()
    return level, TILE_RANGE * u / np.abs(u).max()


def textured_walls(parts: dict[str, list], seed: int = SEED) -> tuple[dict[str, list], np.ndarray, dict]:
    """The ``wall`` segment's meshes cut into tiles, grouped by level.

    Returns
    -------
    (parts, delta, stats)
        ``parts``: ``wall_<k>`` -> [(stem, mesh)] of each level k's tiles per wall file;
        ``delta``: (LEVELS,) the levels' δ; ``stats``: tile count, areas, area-weighted mean δ.
    """
    tiles: dict[tuple, list] = {}
    for stem, mesh in parts[WALL]:
        for cell, poly in tile_pieces(mesh):
            tiles.setdefault((stem, cell), []).append(poly)
    keys = sorted(tiles)
    areas = np.array([sum(_area(p) for p in tiles[k]) for k in keys])
    level, delta = tile_levels(areas, seed)
    out = {f"{WALL}_{k}": [(f"{stem}_{k}", _fan([p for key, lv in zip(keys, level) if lv == k and key[0] == stem
                                                  for p in tiles[key]]))
                           for stem, _ in parts[WALL]] for k in range(LEVELS)}
    stats = {"tiles": len(keys), "area_m2": float(areas.sum()),
             "level_area_m2": [float(areas[level == k].sum()) for k in range(LEVELS)],
             "mean_delta": float(np.sum(areas * delta[level]) / areas.sum())}
    return out, delta, stats


# ----------------------------------------------------------------------------------------------
# The truth the photographs are rendered from
# ----------------------------------------------------------------------------------------------

def _shifted(mesh: g.Mesh) -> g.Mesh:
    return np.asarray(mesh[0], float) + [0.0, FACADE_SIDE * FACADE_SHIFT, 0.0], mesh[1]


def truth_parts(segments: list[dict], parts: dict[str, list], seed: int = SEED):
    """The segments and meshes of the truth: the north building's meshes moved :data:`FACADE_SHIFT`
    behind the facade, the walls textured (:func:`textured_walls`).

    Returns
    -------
    (segments, parts, delta, stats)
        scene.yaml-like segment dicts and ``parts`` for :func:`scenes.urban_canyon_field.photo_scene`,
        the tile levels' δ and the tile statistics.
    """
    tag = dict((s, t) for s, t in uc.SIDES)[FACADE_SIDE]
    moved = {seg: [(stem, _shifted(m) if stem.endswith(f"_{tag}") else m) for stem, m in p] for seg, p in parts.items()}
    tiled, delta, stats = textured_walls(moved, seed)
    out_segments, out_parts = [], {}
    for seg in segments:
        if seg["name"] != WALL:
            out_segments.append(seg)
            out_parts[seg["name"]] = moved[seg["name"]]
            continue
        for k in range(LEVELS):
            name = f"{WALL}_{k}"
            diffuse = (np.asarray(seg["reference"]["diffuse"], float) * (1 + delta[k])).tolist()
            out_segments.append({**seg, "name": name, "meshes": [f"<{stem}>" for stem, _ in tiled[name]],
                                 "reference": {**seg["reference"], "diffuse": diffuse}})
            out_parts[name] = tiled[name]
    return out_segments, out_parts, delta, stats


def car_shares(model, photo, cams: list[Camera]) -> dict[str, float]:
    """Per view, the share of the asphalt's pixels in the model that the car covers in the truth
    (pixel centres of ``cams``, :func:`framework.render.mitsuba_scene.segment_maps`)."""
    from framework.render.mitsuba_scene import segment_maps

    asphalt = [s.name for s in model.segments].index("asphalt")
    car = [i for i, s in enumerate(photo.segments) if s.name in CAR]
    before, after = segment_maps(model, cams), segment_maps(photo, cams)
    return {c.name: float((np.isin(after[c.name], car) & (before[c.name] == asphalt)).sum()
                          / max(int((before[c.name] == asphalt).sum()), 1)) for c in cams}


def wall_seen(photo, delta: np.ndarray, cams: list[Camera]) -> dict[str, float | None]:
    """Per view, the mean δ of the wall pixels (pixel centres): what the view sees of the texture."""
    from framework.render.mitsuba_scene import segment_maps

    names = [s.name for s in photo.segments]
    lookup = np.full(len(names) + 1, np.nan)                       # index -1 (sky): the last, NaN
    for k in range(LEVELS):
        lookup[names.index(f"{WALL}_{k}")] = delta[k]
    out = {}
    for name, ids in segment_maps(photo, cams).items():
        seen = lookup[ids.ravel()]
        seen = seen[np.isfinite(seen)]
        out[name] = float(seen.mean()) if seen.size else None
    return out


def facade_motion(cams: list[Camera]) -> dict[str, dict[str, float] | None]:
    """Per view, how far the facade's shift moves the facade's vertices in the image (pixels:
    median and largest over the vertices in front of the camera and inside the image)."""
    verts = g.merge([uc.facade_wall(FACADE_SIDE), uc.recesses(FACADE_SIDE)[1]])[0]
    out = {}
    for cam in cams:
        pc = verts @ cam.cam_from_world[:, :3].T + cam.cam_from_world[:, 3]
        a, b = cam.project(verts), cam.project(_shifted((verts, None))[0])
        inside = (pc[:, 2] > 0.1) & (a[:, 0] >= 0) & (a[:, 0] <= cam.width) & (a[:, 1] >= 0) & (a[:, 1] <= cam.height)
        d = np.linalg.norm(b - a, axis=1)[inside]
        out[cam.name] = {"median": float(np.median(d)), "max": float(d.max())} if d.size else None
    return out


# ----------------------------------------------------------------------------------------------
# The folder
# ----------------------------------------------------------------------------------------------

def build(folder: Path, *, image: int = IMAGE, spp: int = SPP, seed: int = SEED) -> Path:
    """Write the scene folder.

    Parameters
    ----------
    folder : Path
        Output folder (created).
    image : int
        Width and height of the photographs (200 for the bundled scene; the tests use fewer).
    spp : int
        Samples per pixel of the (supersampled) pinhole renders.
    seed : int
        Seeds urban_canyon_field's draws (intrinsics, gains, noise, sampler), the pose offsets and
        the tiles' levels.
    """
    t0 = time.perf_counter()
    folder = Path(folder)
    made = photographed(folder, image=image, spp=spp, seed=seed, comment=_comment())
    shares = made["measured"]["car_share"]
    names = [c.name for c in made["cams"]]
    car = {"masked": False, "origin": list(CAR_ORIGIN), "size_m": [4.2, 1.8, 1.5],
           "boxes": {k: [{"lo": _r(lo), "hi": _r(hi)} for lo, hi in b] for k, b in field.car_boxes(CAR_ORIGIN).items()},
           "materials": {k: field.EXTRA_MATERIALS[k] for k in CAR},
           "pixels": {n: made["stats"][n]["car"] for n in names},
           "asphalt_share": _r(shares, 4),
           "views": [n for n in names if SHARE_RANGE[0] <= shares[n] <= SHARE_RANGE[1]]}
    truth = truth_of(made, car, image=image, spp=spp, seed=seed)
    (folder / "truth.yaml").write_text(_TRUTH_HEAD + yaml.safe_dump(truth, sort_keys=False, width=100,
                                                                     default_flow_style=None))
    (folder / "README.md").write_text(_readme(truth))
    log.info("%s built in %.1f s", folder.name, time.perf_counter() - t0)
    return folder


def photographed(folder: Path, *, image: int, spp: int, seed: int, comment: str, car_origin=CAR_ORIGIN,
                 materials: dict | None = None) -> dict:
    """The model (urban_canyon_field's, ``comment`` atop scene.yaml) and the photographs of the
    misfit truth (:func:`truth_parts`, rotated poses) with the car, or cars, at ``car_origin`` in
    ``materials`` (:func:`scenes.urban_canyon_field.photo_scene`), written to ``folder``.

    Returns
    -------
    dict
        ``cams``, ``models``, ``gains``, ``stats``, ``offsets``, ``delta``, ``tile_stats`` and
        ``measured`` (``car_share``: :func:`car_shares`, ``wall_seen``, ``motion``, ``facade``).
    """
    from framework.scene import load_scene

    parts, emitters, segments, cams, models = field.write_model(folder, image, seed, comment)
    model = load_scene(folder)                       # before images/ exists: the model, no photographs
    offsets = pose_offsets(cams, seed)
    true_cams = [rotated(c, offsets[c.name]) for c in cams]
    renders = [field.render_camera(c, *m) for c, m in zip(true_cams, models)]
    view_gains = field.gains([c.name for c in cams], seed)
    t_segments, t_parts, delta, tile_stats = truth_parts(segments, parts, seed)
    photo = field.photo_scene(folder, t_segments, emitters, t_parts, renders, car_origin=car_origin,
                              materials=materials)
    codes, _, stats = field.photographs(photo, cams, models, renders, view_gains, spp=spp, seed=seed)
    field.write_images(folder, cams, codes, stats)
    measured = {"car_share": car_shares(model, photo, true_cams), "wall_seen": wall_seen(photo, delta, true_cams),
                "motion": {c.name: image_motion(c, offsets[c.name]) for c in cams},
                "facade": facade_motion(true_cams)}
    return {"cams": cams, "models": models, "gains": view_gains, "stats": stats, "offsets": offsets,
            "delta": delta, "tile_stats": tile_stats, "measured": measured}


def _r(x, digits: int = 6):
    if isinstance(x, dict):
        return {k: _r(v, digits) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_r(v, digits) for v in x]
    return None if x is None else round(float(x), digits)


def truth_of(made: dict, car: dict, *, image: int, spp: int, seed: int) -> dict:
    """truth.yaml's content: :func:`photographed`'s ``made`` and the ``car`` entry."""
    cams, models, view_gains, stats = made["cams"], made["models"], made["gains"], made["stats"]
    offsets, measured, delta, tile_stats = made["offsets"], made["measured"], made["delta"], made["tile_stats"]
    names = [c.name for c in cams]
    return {
        "seed": seed, "image_size": [image, image], "reference_view": field.REFERENCE_VIEW,
        "gains": {n: view_gains[n] for n in names},
        "cameras": {c.name: {"model": m, "params": [float(x) for x in p]} for c, (m, p) in zip(cams, models)},
        "render": {"integrator": "path, max_depth -1 (unbounded)", "spp": spp, "supersample": field.SUPERSAMPLE,
                   "sizes": {n: stats[n]["render"] for n in names}},
        "clipped_pixels": {n: stats[n]["clipped"] for n in names},
        "saturated_pixels": {n: stats[n]["saturated"] for n in names},
        "car": car,
        "pedestrian": {"masked": False,
                       "box": {k: _r(v) for k, v in zip(("origin", "ex", "ey", "ez"), field.pedestrian_box())},
                       "pixels": {n: stats[n]["pedestrian"] for n in names}},
        "pose": {n: {"axis": _r(offsets[n]["axis"]), "angle_rad": _r(offsets[n]["angle"], 8),
                     "px": _r(offsets[n]["px"], 4),
                     "image_motion_px": _r(measured["motion"][n], 4)} for n in names},
        "facade": {"side": "north", "shift_m": [0.0, FACADE_SIDE * FACADE_SHIFT, 0.0],
                   "meshes": [f"{seg}_north" for seg in uc.side_meshes(FACADE_SIDE)],
                   "image_motion_px": {n: _r(measured["facade"][n], 4) for n in names}},
        "tiles": {"segment": WALL, "size_m": TILE, "levels": LEVELS, "delta": _r(delta),
                  "diffuse": "reference x (1 + delta[level]) per channel, specular the reference",
                  "count": tile_stats["tiles"], "area_m2": _r(tile_stats["area_m2"], 3),
                  "level_area_m2": _r(tile_stats["level_area_m2"], 3),
                  "area_weighted_mean_delta": _r(tile_stats["mean_delta"], 9),
                  "seen_mean_delta": _r(measured["wall_seen"], 4)},
    }


_TRUTH_HEAD = """\
# Ground truth of the misfit scene, for evaluation only (the scene loader ignores this file).
# gains: pixel = gain[view][channel] * radiance before noise and encoding; the reference view's are 1.
# car.asphalt_share: share of the model's asphalt pixels (pixel centres, true pose) the car covers.
# pose: true camera = rotation by angle_rad about axis (camera frame) of the COLMAP pose; px = angle x f.
# tiles: the wall's diffuse per tile = reference x (1 + delta[level]); seen_mean_delta: mean delta of a view's wall pixels.
"""


def _comment() -> str:
    return """Generated by `python -m scenes.build urban_canyon_misfit` (scenes/urban_canyon_misfit.py); do not edit.
The model of urban_canyon_field (same meshes, segments, references, light, cameras and COLMAP poses);
its photographs differ from the model: an unmasked parked car, rotated true poses, the north facade
0.1 m behind its mesh, textured walls (README.md, truth.yaml)."""


def _readme(t: dict) -> str:
    car, tiles = t["car"], t["tiles"]
    rows = []
    for n, pose in t["pose"].items():
        fm, seen, motion = t["facade"]["image_motion_px"][n], tiles["seen_mean_delta"][n], pose["image_motion_px"]
        facade = "n/a" if fm is None else f"{fm['median']:.2f} / {fm['max']:.2f}"
        wall = "n/a" if seen is None else f"{100 * seen:+.2f}"
        gains = ", ".join(f"{x:.4f}" for x in t["gains"][n])
        rows.append(f"| {n} | {car['asphalt_share'][n]:.3f} | {car['pixels'][n]} | {pose['px']:.3f} | "
                    f"{motion['centre']:.3f} / {motion['max']:.3f} | {facade} | {wall} | {gains} |")
    lo, hi = min(tiles["delta"]), max(tiles["delta"])
    return f"""# urban_canyon_misfit

Generated by `python -m scenes.build urban_canyon_misfit` (`scenes/urban_canyon_misfit.py`, seed
{t['seed']}); do not edit by hand. The model is `urban_canyon_field`'s — the same `scene.yaml`
(segments, references, light, photometry), meshes, distorted COLMAP cameras and poses — and the
photographs are made the same way (distortion, per-view gains, sensor noise, 8-bit sRGB JPEG;
see `scenes/urban_canyon_field/README.md`), {t['image_size'][0]}x{t['image_size'][1]} px, {t['render']['spp']} spp. What the
photographs hold and the model lacks (`truth.yaml` has every value in machine-readable form):

1. **An unmasked parked car** (there is no `masks/`): the field scene's car ({car['size_m'][0]} x {car['size_m'][1]} x {car['size_m'][2]} m, dark
   paint with a mirror coat, tinted glass), moved to x in [{car['origin'][0]}, {car['origin'][0] + 4.2:g}], y in [{car['origin'][1]},
   {car['origin'][1] + 1.8:g}] (the south curb, in the shade), where it covers {SHARE_RANGE[0]:.0%}-{SHARE_RANGE[1]:.0%} of the asphalt's pixels in
   {' and '.join(f'`{v}`' for v in car['views'])} (share of the model's asphalt pixels whose centre sees the car, at the
   true pose). The pedestrian of urban_canyon_field stays, unmasked.
2. **Rotated poses**: each view's true pose is its COLMAP pose rotated about its centre by
   px / f radians about a random axis of the camera frame, px uniform in [{POSE_PX[0]}, {POSE_PX[1]}] (f in pixels).
3. **The north facade {FACADE_SHIFT} m behind its mesh**: the north building's meshes (wall, window, balcony,
   awning, roof) translated by (0, +{FACADE_SHIFT}, 0) m, along the facade's inward normal.
4. **Textured walls**: the `wall` segment's meshes cut into {tiles['size_m']} m tiles ({tiles['count']} tiles on
   {tiles['area_m2']:.0f} m²), each of diffuse = reference x (1 + δ), δ one of {tiles['levels']} levels from {100 * lo:+.2f} % to
   {100 * hi:+.2f} % drawn per tile; the area-weighted mean δ is {tiles['area_weighted_mean_delta']:.2e}, so
   `scene.yaml`'s reference is the walls' mean. The specular weight is the reference.

## Per view

Car share: of the model's asphalt pixels. Pose: px of the rotation (angle x f), and the image
motion it makes at the principal point / largest over the pixel centres. Facade: motion of the
north facade's vertices in the image (median / largest, px). Wall δ seen: mean δ over the view's
wall pixels (%).

| view | car share | car pixels | pose px | motion centre / max | facade median / max | wall δ seen (%) | gains (R, G, B) |
|---|---|---|---|---|---|---|---|
{chr(10).join(rows)}
"""
