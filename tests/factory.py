"""Tiny seeded scenes for the tests: a ground quad and a box under sky and sun, 16x16 views."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from scenes.cameras import look_at
from scenes.io import PinholeCamera, write_colmap, write_mesh, write_scene_yaml

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
    write_colmap(root / "sparse", [PinholeCamera(f"view_{i}.png", size, size, f, look_at(eyes[i], [0, 0, 0.8]))
                                   for i in range(n_views)])
    return root


def small_copy(name: str, dest: Path, *, size: int, views: list[str]) -> Path:
    """A copy of bundled scene ``name`` whose ``views`` are resampled to ``size`` x ``size`` pixels
    (same pose and field of view), for tests that must stay <= 64x64."""
    import shutil

    from scenes import BUNDLED_DIR
    from scenes.io import read_colmap
    shutil.copytree(Path(BUNDLED_DIR) / name, dest)
    shutil.rmtree(dest / "sparse")
    cams = [c for c in read_colmap(Path(BUNDLED_DIR) / name / "sparse") if c.name in views]
    write_colmap(dest / "sparse", [PinholeCamera(c.name, size, size, c.focal * size / c.width, c.cam_from_world)
                                   for c in cams])
    return dest
