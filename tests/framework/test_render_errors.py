"""Scenes and settings that cannot render: one UserError line each, raised before rendering.

Each case breaks a copy of the tiny scene (factory.make_tiny_scene) one way; without the checks
they ended in Dr.Jit's "operands have incompatible sizes (0, 1)", a crashed process, a quietly
wrong pose or a 30-second wait.
"""
from __future__ import annotations

import dataclasses
import importlib
import logging
import shutil

import numpy as np
import pytest
from factory import edit_scene_yaml, make_problem, make_tiny_scene, run_symbolic
from omegaconf import OmegaConf

from framework.cache import Cache
from framework.errors import ConfigError, EnvironmentSetupError, SceneError
from framework.executor import make_executor
from framework.images import write_exr
from framework.render import checks
from framework.scene import load_scene
from framework.scene.write import pinhole_camera, write_colmap
from scenes.cameras import look_at

SUN = {"type": "directional", "direction": [0.4, 0.3, -0.87], "irradiance": [3.0, 2.9, 2.8]}
SKY = {"type": "constant", "radiance": [0.3, 0.35, 0.45]}


def _emitters(root, emitters):
    edit_scene_yaml(root, lambda desc: desc.update(emitters=emitters))


def _views(root, targets):
    """Replace the COLMAP model by 16x16 views from the tiny scene's eyes towards ``targets``."""
    shutil.rmtree(root / "sparse")
    eyes = [[6, -5, 4], [-6, -5, 3]]
    f = 16 / (2 * np.tan(np.radians(30)))
    write_colmap(root / "sparse", [pinhole_camera(f"view_{i}.png", 16, 16, f, look_at(eye, target))
                                   for i, (eye, target) in enumerate(zip(eyes, targets))])


def _quaternion(root, qwxyz):
    """Write ``qwxyz`` as view_0's rotation in images.txt of a model without rigs and frames
    (as COLMAP < 3.12 writes it: the poses then come from images.txt)."""
    sparse = root / "sparse"
    for name in ("frames.txt", "rigs.txt"):
        (sparse / name).unlink(missing_ok=True)
    lines = (sparse / "images.txt").read_text().splitlines()
    i = next(k for k, line in enumerate(lines) if line.endswith(" view_0.png"))
    fields = lines[i].split()
    fields[1:5] = [str(q) for q in qwxyz]
    lines[i] = " ".join(fields)
    (sparse / "images.txt").write_text("\n".join(lines) + "\n")


AWAY = [[12, -10, 9], [-12, -10, 8]]      # up and away from the ground and the block
CENTRE = [0, 0, 0.8]


@pytest.mark.slow
def test_unlit_scene_errors(tiny_scene):
    _emitters(tiny_scene, [{**SKY, "radiance": [0, 0, 0]}, {**SUN, "irradiance": [0, 0, 0]}])
    with pytest.raises(SceneError, match=r"scene.yaml: no emitter gives light \(every radiance, irradiance "
                                         r"and envmap scale is 0\); give one a positive value"):
        make_problem(tiny_scene)
    write_exr(tiny_scene / "sky.exr", np.full((8, 16, 3), 0.5, np.float32), ("R", "G", "B"))
    _emitters(tiny_scene, [{"type": "envmap", "file": "sky.exr", "scale": 0.0}])
    with pytest.raises(SceneError, match="no emitter gives light"):
        make_problem(tiny_scene)
    _emitters(tiny_scene, [{**SUN, "direction": [0, 0, 1]}])
    with pytest.raises(SceneError, match=r"no light reaches the segments seen by view_0.png, view_1.png: the "
                                         r"directional emitter's direction \[0, 0, 1\] points up \(it is the "
                                         r"direction the light travels: give it z < 0 in scene.yaml\)"):
        make_problem(tiny_scene)


@pytest.mark.slow
def test_blind_view_errors(tiny_scene, caplog):
    """Both views facing away: nothing to estimate, an error naming them. One view facing away:
    a warning, and the inversion runs on the other."""
    _views(tiny_scene, AWAY)
    with pytest.raises(SceneError, match=r"no selected view sees any segment \(view_0.png, view_1.png see "
                                         r"only sky or nothing\): fix their poses in .*sparse or select "
                                         r"other views \(views=...\)"):
        make_problem(tiny_scene)
    _views(tiny_scene, [CENTRE, AWAY[1]])
    with caplog.at_level(logging.WARNING, logger="framework.render.checks"):
        problem = make_problem(tiny_scene)
    assert "view view_1.png sees no segment (only sky or nothing)" in caplog.text
    assert np.isfinite(run_symbolic(problem).estimate).all()


@pytest.mark.slow
def test_blind_view_without_sky_still_inverts(tiny_scene):
    """Under a sun alone, a view facing away gets no event at all: the check only warns, so the
    pass must accept an empty tile (``EventBuffer.compact`` returns no event). One pass: under
    the sun alone the block's mirror weight is seen through a handful of paths, and a refinement
    pass may see none of them (then it is reported unobservable, NaN)."""
    _emitters(tiny_scene, [SUN])
    _views(tiny_scene, [CENTRE, AWAY[1]])
    assert np.isfinite(run_symbolic(make_problem(tiny_scene), refine=0).estimate).all()


def test_camera_pose_errors(tiny_scene):
    scene = load_scene(tiny_scene)
    cam = scene.cameras[0]
    nan = dataclasses.replace(cam, cam_from_world=np.full((3, 4), np.nan))
    with pytest.raises(SceneError, match="the pose of view_0.png has NaN/Inf values; re-export the COLMAP model"):
        checks.check_camera_poses(scene, [nan])
    _quaternion(tiny_scene, [0.5, 0.5, 0.5, 0.4])
    with pytest.raises(SceneError, match=r"sparse/images.txt: the pose of view_0.png is not a rotation \(its "
                                         r"quaternion QW QX QY QZ is not of unit length\); normalise it"):
        make_problem(tiny_scene)
    _quaternion(tiny_scene, [0, 0, 0, 0])
    with pytest.raises(SceneError, match=r"sparse/images.txt: the quaternion \(QW, QX, QY, QZ\) = \(0, 0, 0, 0\) "
                                         r"of view_0.png is not of unit length \(pycolmap reads it as the "
                                         r"identity rotation\); write the view's rotation as a unit quaternion"):
        make_problem(tiny_scene)


@pytest.mark.slow
def test_memory_errors(tiny_scene, monkeypatch):
    """render.spp=4194304 used to crash the process: the smallest tile (64 pixels) would need
    64 x 4194304 samples x 3 events (N_max = 2) x 16 bytes x 3 copies = 36864 MiB. At 4096 spp
    the tile is the whole 16x16 view: 256 x 4096 x 3 x 16 x 3 bytes = 144 MiB."""
    problem = make_problem(tiny_scene, None, "render.spp=4194304", "render.tail_bounces=0")
    with pytest.raises(ConfigError, match=r"render.spp=4194304 needs 36864 MiB for the smallest tile of the "
                                          r"polynomial pass \(64 pixels\), above method.memory_mb=512: lower "
                                          r"render.spp to at most 58254 or raise method.memory_mb to at least 36864"):
        run_symbolic(problem)
    monkeypatch.setattr(checks, "available_memory_bytes", lambda: 2**20)
    with pytest.raises(ConfigError, match=r"the polynomial pass's tiles \(1 at once\) need 144 MiB, but this "
                                          r"machine has 1 MiB available: lower method.memory_mb \(smaller tiles\) "
                                          r"or render.spp"):
        run_symbolic(make_problem(tiny_scene, None, "render.spp=4096", "render.tail_bounces=0"))
    monkeypatch.setattr(checks, "available_memory_bytes", lambda: 0)
    with pytest.raises(ConfigError, match=r"the observation renders' films need 1 MiB, but this machine has 0 MiB "
                                          r"available: resample the views to fewer pixels"):
        make_problem(tiny_scene)


def test_memory_estimates():
    """The machine's available memory is positive and at most its total; a film is counted once
    per copy, whatever its spp."""
    import psutil
    assert 0 < checks.available_memory_bytes() <= psutil.virtual_memory().total
    cam = pinhole_camera("v.png", 200, 100, 100.0, np.hstack([np.eye(3), np.zeros((3, 1))]))
    assert checks.film_bytes([cam], 3) == 200 * 100 * 5 * 4 * checks.FILM_COPIES


def test_dask_scheduler_errors():
    with pytest.raises(EnvironmentSetupError, match=r"the Dask scheduler at tcp://127.0.0.1:1 is unreachable "
                                                    r"\(no answer in 1 s\): start one \(dask scheduler\) or "
                                                    r"drop executor.address"):
        make_executor(OmegaConf.create({"name": "dask", "address": "tcp://127.0.0.1:1", "connect_timeout_s": 1}))
    with pytest.raises(ConfigError, match="executor.connect_timeout_s=0 is out of range"):
        make_executor(OmegaConf.create({"name": "dask", "address": "tcp://127.0.0.1:1", "connect_timeout_s": 0}))


@pytest.mark.slow
def test_failed_render_leaves_whole_cache_entries(tmp_path, monkeypatch):
    """A pass that fails on its second view keeps the first view's entry (whole, loadable) and
    leaves nothing of the second; a write that fails leaves neither an entry nor a temporary file."""
    pp = importlib.import_module("methods.symbolic.system.polynomial_pass")    # the package exports a function of that name
    root = make_tiny_scene(tmp_path / "s", kernels=("diffuse",))
    cache_dir = tmp_path / "cache"
    problem = make_problem(root, None, f"cache.dir={cache_dir}")
    render = pp.render_view_task

    def fail_on_second_view(task, **kwargs):
        if task.view == 1:
            raise RuntimeError("renderer died")
        return render(task, **kwargs)

    monkeypatch.setattr(pp, "render_view_task", fail_on_second_view)
    with pytest.raises(RuntimeError, match="renderer died"):
        run_symbolic(problem, refine=0)
    entries = list((cache_dir / "polynomial_pass").iterdir())
    assert len(entries) == 1 and entries[0].suffix == ".npz"
    monkeypatch.setattr(pp, "render_view_task", render)
    assert run_symbolic(problem, refine=0).extras["views_from_cache"] == ["view_0.png"]

    def no_rename(*args):
        raise OSError("disk full")

    before = sorted((cache_dir / "observed").iterdir())
    monkeypatch.setattr("os.replace", no_rename)
    with pytest.raises(OSError, match="disk full"):
        Cache(cache_dir).store("observed", {"x": 1}, {"image": np.zeros(3)})
    assert sorted((cache_dir / "observed").iterdir()) == before     # no entry, no temporary file
