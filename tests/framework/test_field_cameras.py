"""Distorted COLMAP cameras: the pinhole camera the loader builds (same size and principal point,
f = max(fx, fy)) sees every 3D point where the delivered camera, undistorted, sees it, and
Mitsuba's sensor of that pinhole camera shoots its pixel rays through those points."""
from __future__ import annotations

import numpy as np
import pytest
from factory import make_field_scene

from framework.scene import load_scene
from framework.scene.undistort import pinhole_for, source_pixels

SIZE = 32
#: (COLMAP model, kwargs of factory.distorted): the accepted models, two with fx != fy
CASES = {
    "SIMPLE_RADIAL": ("SIMPLE_RADIAL", {}),
    "RADIAL": ("RADIAL", {}),
    "OPENCV": ("OPENCV", {"fx": 26.0, "fy": 29.5}),
    "PINHOLE fx!=fy": ("PINHOLE", {"fx": 28.0, "fy": 25.0}),
}
PIXEL_TOL = 0.01        # px


def _homogeneous(rays: np.ndarray) -> np.ndarray:
    """(x/z, y/z) -> (x/z, y/z, 1)."""
    rays = np.asarray(rays, dtype=float)
    return np.concatenate([rays, np.ones((len(rays), 1))], axis=1)


def _world(camera, cam_points: np.ndarray) -> np.ndarray:
    """World coordinates of camera-frame points (N, 3)."""
    R, t = camera.cam_from_world[:, :3], camera.cam_from_world[:, 3]
    return (cam_points - t) @ R


@pytest.fixture(params=list(CASES), scope="module")
def field_camera(request, tmp_path_factory):
    """The loaded pinhole Camera of a view photographed by one distorted camera, and its scene."""
    model, kwargs = CASES[request.param]
    root = make_field_scene(tmp_path_factory.mktemp("field") / "scene", [(model, kwargs)], size=SIZE)
    scene = load_scene(root)
    return scene, scene.cameras[0]


def test_pinhole_camera_of_a_distorted_one(field_camera):
    """Camera keeps the size and principal point, takes f = max(fx, fy), records the delivered
    camera, and rebuilds it exactly."""
    _, cam = field_camera
    delivered = cam.delivered()
    assert cam.distortion is not None and delivered.model.name == cam.distortion[0]
    assert np.array_equal(np.asarray(delivered.params), cam.distortion[1])
    assert (cam.width, cam.height) == (delivered.width, delivered.height) == (SIZE, SIZE)
    assert (cam.cx, cam.cy) == (delivered.principal_point_x, delivered.principal_point_y)
    assert cam.f == max(delivered.focal_length_x, delivered.focal_length_y)
    assert np.array_equal(np.asarray(pinhole_for(delivered).params), np.asarray(cam.pinhole().params))


def test_distorted_projection_lands_on_the_pinhole_projection(field_camera):
    """Random visible points: pycolmap's distorted projection, mapped to the pinhole image (the
    inverse of the loader's resampling map), is Camera.project's pixel within 0.01 px."""
    _, cam = field_camera
    delivered, pinhole = cam.delivered(), cam.pinhole()
    rng = np.random.default_rng(0)
    pixels = rng.uniform(1.0, SIZE - 1.0, (200, 2))                    # inside the pinhole image
    cam_points = _homogeneous(pinhole.cam_from_img(pixels)) * rng.uniform(2, 12, (len(pixels), 1))
    world = _world(cam, cam_points)
    distorted = np.asarray(delivered.img_from_cam(cam_points))          # where the photograph has them
    undistorted = np.asarray(pinhole.img_from_cam(_homogeneous(delivered.cam_from_img(distorted))))
    assert np.abs(undistorted - cam.project(world)).max() < PIXEL_TOL
    # the distortion is real: without undistortion the points would be elsewhere
    assert np.abs(distorted - cam.project(world)).max() > 0.2


def test_resampling_map_and_mitsuba_rays_agree(field_camera):
    """Every pinhole pixel centre: the point the loader's resampling reads in the photograph
    (``source_pixels``), put at a random depth, projects by Camera.project onto that pixel
    centre (0.01 px), and Mitsuba's sensor ray of that pixel passes through it (within the
    distance 0.01 px spans at its depth, plus float32 rounding)."""
    from framework.render.mitsuba_scene import MitsubaScene
    scene, cam = field_camera
    delivered = cam.delivered()
    read_at = source_pixels(source=delivered, target=cam.pinhole()).reshape(-1, 2)
    depth = np.random.default_rng(1).uniform(2, 12, (len(read_at), 1))
    world = _world(cam, _homogeneous(delivered.cam_from_img(read_at)) * depth)
    ys, xs = np.divmod(np.arange(SIZE * SIZE), SIZE)
    centres = np.stack([xs + 0.5, ys + 0.5], axis=1)
    assert np.abs(cam.project(world) - centres).max() < PIXEL_TOL
    ray = MitsubaScene(scene, [cam], spp=1).pixel_centre_rays(0)
    o, d = np.array(ray.o, dtype=float).T, np.array(ray.d, dtype=float).T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    distance = np.linalg.norm(np.cross(world - o, d), axis=1)
    along = np.einsum("ij,ij->i", world - o, d)
    assert (along > 0).all()
    assert (distance < PIXEL_TOL * along / cam.f + 1e-5 * np.linalg.norm(world, axis=1)).all()
