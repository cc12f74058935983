"""Shared builders of the tests: tiny seeded scenes (a ground quad and a box under sky and sun,
16x16 views), problems, method runs, and the Monte Carlo statistics the tolerances are built on."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from framework.scene.write import pinhole_camera, write_colmap, write_mesh, write_scene_yaml
from scenes.cameras import look_at, resized

QUAD_FACES = np.array([[0, 1, 2], [0, 2, 3]])


def quad(x0, x1, y0, y1, z=0.0) -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], float)
    return v, QUAD_FACES


def box(c, h) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box centred at c with half-sizes h, outward faces."""
    s = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    v = np.asarray(c, float) + s * np.asarray(h, float)
    f = np.array([[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4],
                  [2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5]])
    return v, f


def make_tiny_scene(root: Path, *, size: int = 16, channels: str = "rgb", n_views: int = 2,
                    kernels=("diffuse", "specular")) -> Path:
    """Write a scene folder: segments ground (quad) and block (box), constant sky + sun."""
    root = Path(root)
    write_mesh(root / "meshes/ground.ply", *quad(-5, 5, -5, 5))
    write_mesh(root / "meshes/block.ply", *box([0, 0, 1], [1, 1, 1]))
    val = (lambda v: v) if channels == "rgb" else (lambda v: float(np.mean(v)))
    ref_ground = {"diffuse": val([0.5, 0.4, 0.3])}
    ref_block = {"diffuse": val([0.3, 0.6, 0.5])}
    if "specular" in kernels:
        ref_ground["specular"] = val([0.1, 0.1, 0.1])
        ref_block["specular"] = val([0.2, 0.2, 0.2])
    write_scene_yaml(root / "scene.yaml", {
        "name": "tiny", "channels": channels,
        "segments": [
            {"name": "ground", "meshes": ["meshes/ground.ply"], "kernels": list(kernels), "reference": ref_ground},
            {"name": "block", "meshes": ["meshes/block.ply"], "kernels": list(kernels), "reference": ref_block}],
        "emitters": [{"type": "constant", "radiance": val([0.3, 0.35, 0.45])},
                     {"type": "directional", "direction": [0.4, 0.3, -0.87], "irradiance": val([3.0, 2.9, 2.8])}],
    })
    f = size / (2 * np.tan(np.radians(30)))
    eyes = [[6, -5, 4], [-6, -5, 3], [5, 6, 5], [-5, 6, 4]]
    write_colmap(root / "sparse", [pinhole_camera(f"view_{i}.png", size, size, f, look_at(eyes[i], [0, 0, 0.8]))
                                   for i in range(n_views)])
    return root


def edit_scene_yaml(root: Path, fn) -> None:
    """Apply ``fn`` to the parsed ``root/scene.yaml`` (a dict, edited in place) and write it back."""
    import yaml
    path = Path(root) / "scene.yaml"
    desc = yaml.safe_load(path.read_text())
    fn(desc)
    path.write_text(yaml.safe_dump(desc, sort_keys=False))


def snapshot(root: Path) -> dict:
    """Every path below ``root`` with its bytes (None for a folder), to compare before and after."""
    return {str(p.relative_to(root)): p.read_bytes() if p.is_file() else None for p in Path(root).rglob("*")}


def small_copy(name: str, dest: Path, *, size: int, views: list[str]) -> Path:
    """A copy of bundled scene ``name`` whose ``views`` are resampled to ``size`` x ``size`` pixels
    (same pose and field of view), for tests that must stay <= 64x64."""
    import shutil

    from framework.scene import load_scene
    from scenes import BUNDLED_DIR
    shutil.copytree(Path(BUNDLED_DIR) / name, dest)
    shutil.rmtree(dest / "sparse")
    cams = [c for c in load_scene(Path(BUNDLED_DIR) / name).cameras if c.name in views]
    write_colmap(dest / "sparse", [resized(c, size) for c in cams])
    return dest


# ------------------------------------------------------------------------------------------------
# Problems and method configurations
# ------------------------------------------------------------------------------------------------
def method_config(name: str, **overrides):
    """The method's shipped configuration (Hydra defaults resolved) with ``overrides``."""
    from omegaconf import open_dict

    from framework.config import method_defaults
    cfg = method_defaults(name)
    with open_dict(cfg):
        for key, value in overrides.items():
            cfg[key] = value
    return cfg


def tiny_problem(root, *, kernels=("diffuse",), spp=16, budget=100, n_views=1, obs_spp=256, seed=0):
    """A Problem on make_tiny_scene: observations rendered at the references, ``obs_spp``, odd seed.

    Observations use ``max_depth = N_max + 1`` (N_max = 3), as the inversions do, so the
    estimates are unbiased up to Monte-Carlo noise. ``seed`` is both the observation stream and
    the run's seed (the tests use 0; the tolerance audits vary it).
    """
    from framework.config import RunSettings
    from framework.observe import render_references
    from framework.registry import Problem
    from framework.scene import load_scene
    scene = load_scene(make_tiny_scene(root, kernels=kernels, n_views=n_views))
    cams = list(scene.cameras)
    obs = render_references(scene, cams, spp=obs_spp, max_depth=4, seed=seed)
    settings = RunSettings(spp=spp, max_bounces=3, budget_renders=budget, seed=seed, cache_dir=None)
    return Problem(scene=scene, cameras=cams, observed={c.name: o for c, o in zip(cams, obs)},
                   parameters=scene.parameters(), settings=settings)


def compose_config(scene_dir, *overrides):
    """The run configuration for ``scene_dir``, small and fast by default, no cache."""
    from framework.config import compose
    base = [f"scene.dir={scene_dir}", "render.spp=8", "observe.spp=64", "render.max_bounces=2",
            "observe.max_depth=3", "cache.dir=null"]
    return compose(base + list(overrides))


def make_problem(scene_dir, views=None, *overrides):
    """A :class:`Problem` of ``scene_dir`` (all views, or the named ones), as a run builds it."""
    from framework.experiment import prepare
    views_override = ["views=all"] if views is None else [f"views=[{','.join(views)}]"]
    problem, _, _ = prepare(compose_config(scene_dir, *views_override, *overrides))
    return problem


def run_method(name: str, problem, **overrides):
    """Run the registered method ``name`` with its shipped options and ``overrides``."""
    from framework.registry import get_method
    return get_method(name)(method_config(name, **overrides)).run(problem)


def run_symbolic(problem, **overrides):
    return run_method("symbolic", problem, **overrides)


def run_iterative(problem, **overrides):
    return run_method("iterative", problem, **overrides)


def run_differentiable(problem, **overrides):
    return run_method("differentiable", problem, **overrides)


def view_systems(problem, params, x0, *, max_bounces: int, spp: int, seed: int = 0, prob_floor: float = 0.1,
                 memory_mb: float = 512, tail_bounces: int = 0, cross_gram: bool = True) -> list:
    """Each view's own ``(GramSystem, TiledCoefficients)`` as :func:`polynomial_pass` renders them
    (same seeds and tiles): the pass itself keeps only their sum."""
    from methods.symbolic.system.polynomial_pass import render_view_task, tile_pixels_for, view_task
    tile = tile_pixels_for(memory_mb, spp, max_bounces, problem.n_channels, tail_bounces)
    return [render_view_task(view_task(problem, params, x0, max_bounces, i, spp=spp, seed=seed, prob_floor=prob_floor,
                                       tile_pixels=tile, cross_gram=cross_gram, tail_bounces=tail_bounces),
                             variant=problem.settings.variant)
            for i in range(len(problem.cameras))]


def kernels_per_call(call, args) -> list[int]:
    """Dr.Jit kernels compiled (or loaded from the disk cache, not found in this process's
    memory) by ``call(a)`` for each ``a`` of ``args``, in order
    (:class:`framework.render.jit_timing.CompileTimer`)."""
    from framework.render.jit_timing import CompileTimer
    counts = []
    for a in args:
        with CompileTimer() as timer:
            call(a)
        counts.append(timer.kernels)
    return counts


def fresh_weights(problem, n: int, *, seed: int = 0) -> list[np.ndarray]:
    """``n`` random (P, C) weight arrays in [0.05, 0.45] (feasible for up to two kernels)."""
    rng = np.random.default_rng(seed)
    return [rng.uniform(0.05, 0.45, (len(problem.parameters), problem.n_channels)) for _ in range(n)]


def max_error(problem, result) -> float:
    """max |ρ - ρ_ref| over the parameters and channels of a method's result."""
    return float(np.max(np.abs(result.estimate - problem.scene.reference(problem.parameters))))


# ------------------------------------------------------------------------------------------------
# Monte Carlo statistics
# ------------------------------------------------------------------------------------------------
def mean_and_se(samples, axis=0) -> tuple[np.ndarray, np.ndarray]:
    """Sample mean along ``axis`` and its standard error std / sqrt(n) (std with ddof 0: the
    samples are many identically distributed pixels or BSDF draws)."""
    x = np.asarray(samples)
    return x.mean(axis), x.std(axis) / np.sqrt(x.shape[axis])


def mean_difference(a, b) -> tuple[np.ndarray, np.ndarray]:
    """Two sets of independent repetitions of two estimators (repetitions along axis 0): the
    difference of their means and its standard error sqrt(var_a / R_a + var_b / R_b), from the
    sample variances (ddof 1) of the repetitions."""
    a, b = np.asarray(a), np.asarray(b)
    diff = a.mean(0) - b.mean(0)
    se = np.sqrt(a.var(0, ddof=1) / a.shape[0] + b.var(0, ddof=1) / b.shape[0])
    return diff, se


def run_street_cli(tmp_path, folder, *overrides, method: str = "symbolic") -> dict:
    """``python -m framework.run method=<method>`` on the scene ``folder`` (4 spp, observations
    at 16 spp, cached under ``tmp_path``): its results.json (asserts a zero exit status)."""
    import json
    import os
    import subprocess
    import sys
    args = [f"method={method}", f"scene.dir={folder}", "render.spp=4", "observe.spp=16", *overrides,
            "report=false", f"hydra.run.dir={tmp_path / 'run'}", f"cache.dir={tmp_path / 'cache'}"]
    proc = subprocess.run([sys.executable, "-m", "framework.run", *args], capture_output=True, text=True,
                          timeout=300, env=dict(os.environ, HYDRA_FULL_ERROR="0"))
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads((tmp_path / "run" / "results.json").read_text())


# ------------------------------------------------------------------------------------------------
# Field photographs: distorted cameras, 8/16-bit files, masks
# ------------------------------------------------------------------------------------------------
#: distortion coefficients of the delivered cameras the field tests use (moderate barrel / pincushion)
FIELD_MODELS = {
    "SIMPLE_RADIAL": (-0.08,),
    "RADIAL": (-0.06, 0.01),
    "OPENCV": (-0.05, 0.008, 0.001, -0.002),
}


def distorted(camera, model: str, coefficients=None, *, fx: float | None = None, fy: float | None = None):
    """The view ``camera`` (a pinhole :class:`Camera`) as photographed by a COLMAP ``model`` camera
    of the same pose, size and principal point, focal lengths ``fx``, ``fy`` (default ``camera.f``;
    SIMPLE_RADIAL and RADIAL have one, ``fx``) and distortion ``coefficients`` (default
    :data:`FIELD_MODELS`): the Camera the loader builds from it (pinhole f = max(fx, fy))."""
    from dataclasses import replace
    fx = camera.f if fx is None else fx
    fy = fx if fy is None or model in ("SIMPLE_RADIAL", "RADIAL", "SIMPLE_PINHOLE") else fy
    coefficients = FIELD_MODELS.get(model, ()) if coefficients is None else tuple(coefficients)
    focal = (fx,) if model in ("SIMPLE_RADIAL", "RADIAL", "SIMPLE_PINHOLE") else (fx, fy)
    params = tuple(float(x) for x in (*focal, camera.cx, camera.cy, *coefficients))
    return replace(camera, f=max(fx, fy), distortion=(model, params))


def write_field_colmap(sparse_dir: Path, cameras) -> Path:
    """A text COLMAP model of ``cameras`` with each view's delivered camera (``Camera.delivered``:
    its distorted model where it has one), camera and image ids 1..n."""
    import pycolmap
    rec = pycolmap.Reconstruction()
    for i, cam in enumerate(cameras, start=1):
        colmap_camera = cam.delivered()
        colmap_camera.camera_id = i
        rec.add_camera_with_trivial_rig(colmap_camera)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(np.asarray(cam.cam_from_world[:, :3], float)),
                                np.asarray(cam.cam_from_world[:, 3], float))
        rec.add_image_with_trivial_frame(pycolmap.Image(name=cam.name, camera_id=i, image_id=i), pose)
    Path(sparse_dir).mkdir(parents=True, exist_ok=True)
    rec.write_text(str(sparse_dir))
    return Path(sparse_dir)


def make_field_scene(root: Path, models=("OPENCV",), *, size: int = 16, names=None, **tiny) -> Path:
    """:func:`make_tiny_scene` with one view per entry of ``models`` (a COLMAP model name, or
    (name, kwargs of :func:`distorted`)) photographed by that camera, named ``names`` (default
    ``view_<i>.png``). No images/ yet."""
    from framework.scene import load_scene
    root = make_tiny_scene(root, size=size, n_views=len(models), **tiny)
    cams = load_scene(root).cameras
    out = []
    for i, (cam, entry) in enumerate(zip(cams, models)):
        model, kwargs = (entry, {}) if isinstance(entry, str) else entry
        named = cam if names is None else _renamed(cam, names[i])
        out.append(distorted(named, model, **kwargs))
    import shutil
    shutil.rmtree(root / "sparse")
    write_field_colmap(root / "sparse", out)
    return root


def _renamed(camera, name: str):
    from dataclasses import replace
    return replace(camera, name=name)


def write_png16(path: Path, codes: np.ndarray) -> Path:
    """Write ``(H, W)``, ``(H, W, 1)``, ``(H, W, 3)`` or ``(H, W, 4)`` 16-bit codes as a PNG (Pillow
    writes 16 bits only for grey): IHDR, one zlib IDAT of unfiltered rows, IEND."""
    import struct
    import zlib
    a = np.asarray(codes)
    a = a[..., None] if a.ndim == 2 else a
    h, w, c = a.shape
    colour_type = {1: 0, 2: 4, 3: 2, 4: 6}[c]
    rows = b"".join(b"\0" + np.ascontiguousarray(a[y], ">u2").tobytes() for y in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, colour_type, 0, 0, 0))
                           + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))
    return Path(path)


def write_png8(path: Path, codes: np.ndarray, *, fmt: str = "PNG", **save) -> Path:
    """Write ``(H, W)`` or ``(H, W, C)`` 8-bit codes with Pillow (``fmt`` PNG or JPEG)."""
    from PIL import Image
    a = np.asarray(codes, np.uint8)
    a = a[..., 0] if a.ndim == 3 and a.shape[2] == 1 else a
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.ascontiguousarray(a)).save(path, format=fmt, **save)
    return Path(path)


def scene_error_message(root, match: str) -> str:
    """The SceneError message of loading ``root``: it matches ``match`` and is one line."""
    import pytest

    from framework.errors import SceneError
    from framework.scene import load_scene
    with pytest.raises(SceneError, match=match) as info:
        load_scene(root)
    message = str(info.value)
    assert "\n" not in message and "\r" not in message
    return message


def ad_and_fd_gradients(problem, *, spp: int, rho: float, repeats: int, step: float):
    """``(ad, fd)``: ``repeats`` independent AD and finite-difference estimates ``(repeats, P, C)``
    of dε/dρ at ρ = ``rho`` (every weight and channel) on the first view of ``problem``.

    AD: the differentiable method's own pass (``_Fit.cost_and_gradient``: primal and adjoint
    renders at independent seeds), i.e. ``2 (I_a - obs) · dI_b/dρ``, the gradient of the
    expected image's cost. FD: the same from primal renders only, ``2 (I_r - obs) ·
    (I_c(ρ + h e_j) - I_c(ρ - h e_j)) / 2h`` with common random numbers (seed ``c`` on both
    sides) and the residual from an independent seed ``r``.
    """
    import dataclasses

    from methods import _common as C
    from methods.differentiable import DifferentiableMethod, _Fit
    ledger = C.RenderLedger(10 ** 6, desc="gradient test")
    options = DifferentiableMethod.options_from(method_config("differentiable", spp_grad=spp))
    problem = dataclasses.replace(problem, settings=dataclasses.replace(problem.settings, spp=spp))
    fit = _Fit(problem, ledger, options)
    x = np.full((len(problem.parameters), problem.n_channels), rho)
    obs = C.observed_list(problem)[0]

    def render(r, seed):
        fit.write(r, grad=False)
        return fit.ms.render(0, spp=spp, seed=seed)

    ad = np.array([fit.cost_and_gradient(x, it)[1] for it in range(repeats)])
    fd = np.zeros_like(ad)
    for s in range(repeats):
        residual = 2 * (render(x, 100_001 + 2 * s) - obs)
        for j in range(len(problem.parameters)):
            up, down = x.copy(), x.copy()
            up[j] += step
            down[j] -= step
            diff = render(up, 200_001 + 2 * s) - render(down, 200_001 + 2 * s)
            fd[s, j] = np.sum(residual * diff, axis=(0, 1)) / (2 * step)
    ledger.close()
    return ad, fd


# ------------------------------------------------------------------------------------------------
# The command line
# ------------------------------------------------------------------------------------------------
def cli(args, cwd, env=None, **kwargs):
    """``python -m framework.run *args`` in ``cwd`` with this checkout first on the path (Hydra's
    full error off, ``env`` added to the environment); the completed process."""
    import os
    import subprocess
    import sys

    import framework.run
    env = dict(os.environ, HYDRA_FULL_ERROR="0", PYTHONPATH=str(Path(framework.run.__file__).parents[1]),
               **(env or {}))
    return subprocess.run([sys.executable, "-m", "framework.run", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300, **kwargs)


def error_line(proc) -> str:
    """The one line a refused run prints on stderr (its exit status 2 checked)."""
    assert proc.returncode == 2, proc.stderr[-2000:]
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, proc.stderr[-2000:]
    return lines[0]
