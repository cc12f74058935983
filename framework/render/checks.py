"""Checks run before rendering, so that a scene or setting that cannot work fails with one line.

Without them such inputs end deep inside Dr.Jit: a scene no light reaches leaves the polynomial
pass without a single event ("operands have incompatible sizes (0, 1)"), a sample count too large
for memory crashes the process, and a bad camera pose renders quietly wrong. Each check raises a
:class:`~framework.errors.UserError` naming what is wrong and the fix:

- :func:`check_views`: the two checks below, on the views of a run;
- :func:`check_camera_poses`: every ``cam_from_world`` is a finite rotation, and the COLMAP
  quaternion behind an identity rotation has unit length;
- :func:`check_lit_and_seen`: some view sees a segment, and light reaches a segment it sees;
- :func:`check_memory`: an allocation fits the memory this machine has available
  (:func:`available_memory_bytes`); :func:`film_bytes` sizes a path render's.
"""
from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from framework.errors import ConfigError, SceneError
from framework.render.mitsuba_scene import MitsubaScene
from framework.scene import Camera, Scene

log = logging.getLogger(__name__)
MiB = 2**20
ROTATION_TOL = 1e-5       # |RᵀR - I| allowed: COLMAP writes 17 digits, pycolmap builds R in double
CHECK_SEED = 1            # fixed: the check is deterministic (any light path found is real)
COARSE_STRIDE = 16        # lit check: every 16th seen pixel first, all of them only if none is lit
#: A path render (``mi.render`` on LLVM) holds its film a few times (image block, developed
#: bitmap, numpy copy); measured flat in spp (16x16 px from 1 to 65536 spp: same peak memory),
#: since the wavefront runs as one kernel whose per-sample state never reaches memory.
FILM_COPIES = 4


def check_views(scene: Scene, cameras: list[Camera], *, max_depth: int = -1, weights: dict | None = None
                ) -> dict[str, tuple[int, bool]]:
    """:func:`check_camera_poses`, then :func:`check_lit_and_seen` (whose result it returns):
    every check a run needs on its views before anything is rendered."""
    check_camera_poses(scene, cameras)
    return check_lit_and_seen(scene, cameras, max_depth=max_depth, weights=weights)


# ------------------------------------------------------------------------------------------------
# Camera poses
# ------------------------------------------------------------------------------------------------
def check_camera_poses(scene: Scene, cameras: list[Camera]) -> None:
    """Raise :class:`SceneError` for a view whose pose is not a rotation and a translation.

    A quaternion that is not of unit length gives a scaled, sheared ``cam_from_world``; a zero
    quaternion, or one of the form ``(w, 0, 0, 0)``, gives exactly the identity in pycolmap
    (measured with pycolmap 4.2: its matrix formula hides the norm). So an exact identity
    rotation sends this check back to the COLMAP model for the stored quaternion.
    """
    for cam in cameras:
        R = np.asarray(cam.cam_from_world, float)[:, :3]
        if not np.isfinite(cam.cam_from_world).all():
            raise SceneError(f"{_pose_file(scene)}: the pose of {cam.name} has NaN/Inf values; "
                             "re-export the COLMAP model")
        if np.abs(R.T @ R - np.eye(3)).max() > ROTATION_TOL or np.linalg.det(R) < 0:
            raise SceneError(f"{_pose_file(scene)}: the pose of {cam.name} is not a rotation "
                             "(its quaternion QW QX QY QZ is not of unit length); normalise it")
        if np.array_equal(R, np.eye(3)):
            _check_unit_quaternion(scene, cam)


def _check_unit_quaternion(scene: Scene, cam: Camera) -> None:
    """The stored quaternion of ``cam`` (read again from the COLMAP model) has unit length."""
    sparse = _sparse(scene)
    if not sparse.is_dir():
        return          # a model built in memory: its identity rotation is what it says
    import pycolmap
    rec = pycolmap.Reconstruction(str(sparse))
    for image in rec.images.values():
        if image.name == cam.name:
            q = np.asarray(image.cam_from_world().rotation.quat, float)     # x, y, z, w
            if abs(np.linalg.norm(q) - 1.0) > ROTATION_TOL:
                wxyz = ", ".join(f"{v:g}" for v in (q[3], q[0], q[1], q[2]))
                raise SceneError(f"{_pose_file(scene)}: the quaternion (QW, QX, QY, QZ) = ({wxyz}) of "
                                 f"{cam.name} is not of unit length (pycolmap reads it as the identity "
                                 "rotation); write the view's rotation as a unit quaternion")


def _sparse(scene: Scene) -> Path:
    return Path(scene.root) / "sparse"


def _pose_file(scene: Scene) -> Path:
    """The COLMAP file the poses were read from (``Scene.pose_source``), else the model folder."""
    source = getattr(scene, "pose_source", "")
    return Path(scene.root) / source if source else _sparse(scene)


# ------------------------------------------------------------------------------------------------
# Light and visibility
# ------------------------------------------------------------------------------------------------
def check_lit_and_seen(scene: Scene, cameras: list[Camera], *, max_depth: int = -1,
                       weights: dict | None = None, views_option: bool = True) -> dict[str, tuple[int, bool]]:
    """Raise :class:`SceneError` when no parameter can be observed from ``cameras``.

    A view *sees* a segment through the centre of a usable pixel (:meth:`MitsubaScene.segment_map`,
    and a non-zero ``weights`` entry where the scene has pixel weights: masks, saturated or black
    pixels of its photographs); it is *lit* when one path-traced sample along such a ray (``path``
    with ``max_depth``, every kernel weight ``1/K`` of its segment, fixed seed) carries light. A
    pixel's value depends on ρ only through paths whose first hit is a segment, so when no view
    is lit every parameter is unobservable. The same rule holds for synthetic observations and
    photographs: a view with no usable pixel, or whose usable pixels see only sky, or whose seen
    segments no light reaches, constrains no parameter (:func:`view_problems` says why), and
    when that is every view the run has nothing to fit.

    Parameters
    ----------
    scene : Scene
    cameras : list of Camera
    max_depth : int
        Mitsuba ``max_depth`` of the paths, -1 unbounded: pass the inversion's own depth
        (``render.max_bounces + render.tail_bounces + 1``), since light that needs more
        reflections reaches none of its renders.
    weights : dict, optional
        view name -> ``(H, W)`` pixel weights (0: unusable); None: every pixel usable.
    views_option : bool, default True
        Whether the caller can select other views (a run's ``views=...``), so that the messages
        may suggest it; the converter has no such option.

    Returns
    -------
    dict
        view name -> (usable pixels that see a segment, whether light reaches them).

    Raises
    ------
    SceneError
        When every emitter is black, when no view has a usable pixel, when no view sees a
        segment, or when light reaches no segment any view sees.

    Notes
    -----
    Cost: a ray cast per pixel, and one path sample on every 16th seen pixel, then (only for a
    view none of those lit) on every seen pixel.
    """
    _check_some_emitter_shines(scene)
    _check_environments_sum(scene)
    ms = MitsubaScene(scene, cameras, spp=1, integrator={"type": "path", "max_depth": int(max_depth)})
    params = scene.parameters()
    ms.set_weights(np.array([[1.0 / len(scene.segments[p.segment].kernels)] * len(scene.channels)
                             for p in params]), params)
    weights = weights or {}
    found = {cam.name: _seen_and_lit(ms, i, weights.get(cam.name)) for i, cam in enumerate(cameras)}
    unusable = [c.name for c in cameras if c.name in weights and not np.any(np.asarray(weights[c.name]) > 0)]
    blind = [name for name, (seen, _) in found.items() if seen == 0 and name not in unusable]
    dark = [name for name, (seen, lit) in found.items() if seen and not lit]
    select = "select other views (views=...)" if views_option else ""
    if len(unusable) == len(found):
        raise SceneError(f"no selected view has a usable pixel ({', '.join(unusable)}: every pixel masked, "
                         "saturated or black): nothing to fit; fix the photographs or masks"
                         f"{', or ' + select if select else ''}")
    if len(blind) + len(unusable) == len(found):
        raise SceneError(f"no selected view sees any segment ({', '.join(blind)} see only sky or nothing"
                         f"{' in their usable pixels' if weights else ''}): fix their poses in {_sparse(scene)}"
                         f"{' or ' + select if select else ''}")
    if len(blind) + len(dark) + len(unusable) == len(found):
        raise SceneError(f"no light reaches the segments seen by {', '.join(dark)}: {_light_hint(scene, max_depth)}")
    for name, why in view_problems(found, weights).items():
        log.warning("view %s %s: it constrains no parameter and is left out of the fit; %s", name, why,
                    "check its pose or leave it out of views" if "sees no segment" in why else
                    "check it or leave it out of views")
    return found


def view_problems(found: dict[str, tuple[int, bool]], weights: dict | None = None) -> dict[str, str]:
    """view name -> why it constrains no parameter, for the views of ``found``
    (:func:`check_lit_and_seen`'s result) that do not; the others are absent."""
    weights = weights or {}
    out = {}
    for name, (seen, lit) in found.items():
        if name in weights and not np.any(np.asarray(weights[name]) > 0):
            out[name] = "has no usable pixel (every pixel masked, saturated or black)"
        elif seen == 0:
            out[name] = "sees no segment (only sky or nothing)" + (" in its usable pixels" if name in weights else "")
        elif not lit:
            out[name] = "gets no light on the segments it sees"
    return out


def _check_environments_sum(scene: Scene) -> None:
    """Raise when two environment images (``envmap``, a ``sunsky``'s sky) differ in size: Mitsuba
    renders one environment per scene, so several are summed into one image
    (:func:`~framework.render.mitsuba_scene.summed_environment`), texel by texel."""
    env = [e for e in scene.emitters if e.type == "envmap"]
    sizes = {e.image.shape[:2] for e in env}
    if len(sizes) > 1:
        (a, b) = env[0], next(e for e in env if e.image.shape[:2] != env[0].image.shape[:2])
        raise SceneError(f"{Path(scene.root) / 'scene.yaml'}: emitters {a.source} and {b.source} are environment "
                         f"images of different sizes ({a.image.shape[1]}x{a.image.shape[0]} and "
                         f"{b.image.shape[1]}x{b.image.shape[0]}); Mitsuba renders one environment, so they are "
                         "summed texel by texel: resample one to the other's size")


def _check_some_emitter_shines(scene: Scene) -> None:
    """Raise when every emitter's radiance, irradiance or scale x image is 0 (or negative)."""
    values = [m.radiance for m in scene.meshes if m.radiance is not None]
    for e in scene.emitters:
        if e.type == "envmap":
            values.append(e.scale * np.max(e.image))
        elif e.type in ("constant", "directional"):
            values.append(e.radiance if e.type == "constant" else e.irradiance)
    if not any(np.any(np.asarray(v) > 0) for v in values):
        raise SceneError(f"{Path(scene.root) / 'scene.yaml'}: no emitter gives light (every radiance, "
                         "irradiance and envmap scale is 0); give one a positive value")


def _seen_and_lit(ms: MitsubaScene, view: int, weights=None) -> tuple[int, bool]:
    """(usable pixels of ``view`` whose centre sees a segment, whether a path sample from one
    carries light); ``weights``: the view's ``(H, W)`` pixel weights (0: unusable), or None.

    Every :data:`COARSE_STRIDE`-th seen pixel first: in a lit view that settles it at a fraction
    of the cost; only a view none of those lit is traced in full.
    """
    seen_map = ms.segment_map(view).ravel() >= 0
    if weights is not None:
        seen_map &= np.asarray(weights).ravel() > 0
    seen = np.flatnonzero(seen_map)
    lit = len(seen) > 0 and (_any_lit(ms, view, seen[::COARSE_STRIDE]) or _any_lit(ms, view, seen))
    return len(seen), bool(lit)


def _any_lit(ms: MitsubaScene, view: int, pixels: np.ndarray) -> bool:
    """Whether one path sample through the centre of any of ``pixels`` carries light."""
    import mitsuba as mi
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(CHECK_SEED, len(pixels))
    L, _, _ = ms.scene.integrator().sample(ms.scene, sampler, ms.pixel_centre_rays(view, pixels))
    radiance = np.array(L).reshape(len(pixels), -1)
    return bool((np.isfinite(radiance).all(axis=1) & (radiance > 0).any(axis=1)).any())


def _light_hint(scene: Scene, max_depth: int) -> str:
    """How to light the scene: a sun pointing up is the likely culprit when there is one."""
    for e in scene.emitters:
        if e.type == "directional" and e.direction[2] > 0:
            d = ", ".join(f"{v:.3g}" for v in e.direction)
            return (f"the directional emitter's direction [{d}] points up (it is the direction the light "
                    "travels: give it z < 0 in scene.yaml) and nothing else lights them")
    within = f" within {max_depth - 1} reflections (raise render.max_bounces, or" if max_depth > 0 else " ("
    return f"every emitter of {Path(scene.root) / 'scene.yaml'} misses them{within} add or move an emitter)"


# ------------------------------------------------------------------------------------------------
# Memory
# ------------------------------------------------------------------------------------------------
def available_memory_bytes() -> int:
    """Memory this process can still allocate: the system's available memory (psutil, else free
    pages), lowered to the cgroup v2 limit's headroom when the process runs in one."""
    try:
        import psutil
        free = int(psutil.virtual_memory().available)
    except ImportError:
        free = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    return min(free, _cgroup_headroom())


def _cgroup_headroom() -> int:
    """``memory.max - memory.current`` of this process's cgroup (v2); unbounded when absent."""
    root = Path("/sys/fs/cgroup")
    try:
        limit = (root / "memory.max").read_text().strip()
        if limit == "max":
            return 2**63
        return int(limit) - int((root / "memory.current").read_text())
    except (OSError, ValueError):
        return 2**63


def check_memory(need_bytes: float, what: str, fix: str) -> None:
    """Raise :class:`ConfigError` when ``need_bytes`` exceed :func:`available_memory_bytes`.

    ``what`` names the allocation ("the polynomial pass's tiles"), ``fix`` the settings to change.
    """
    have = available_memory_bytes()
    if need_bytes > have:
        raise ConfigError(f"{what} need {-(-int(need_bytes) // MiB)} MiB, but this machine has "
                          f"{have // MiB} MiB available: {fix}")


def film_bytes(cameras: list[Camera], n_channels: int) -> int:
    """Memory of a path render of the largest of ``cameras`` (films of C + alpha + weight floats)."""
    pixels = max(c.width * c.height for c in cameras)
    return pixels * (n_channels + 2) * 4 * FILM_COPIES
