"""Bad input: one SceneError/ConfigError per case, with a message naming the file and the fix."""
from __future__ import annotations

import numpy as np
import pytest
from factory import edit_scene_yaml

from framework.errors import ConfigError, EnvironmentSetupError, SceneError
from framework.images import write_exr
from framework.scene import load_scene


def _images(root, *, shape=(16, 16, 3), value=0.2, names=("R", "G", "B"), skip=()):
    (root / "images").mkdir(exist_ok=True)
    for i in range(2):
        if f"view_{i}" in skip:
            continue
        img = np.full(shape, value, np.float32)
        write_exr(root / "images" / f"view_{i}.exr", img, names)


def _write_one_camera(sparse, camera_line):
    """A COLMAP text model written by hand (format of COLMAP's docs): one camera, one image."""
    sparse.mkdir(parents=True, exist_ok=True)
    (sparse / "cameras.txt").write_text(f"1 {camera_line}\n")
    (sparse / "images.txt").write_text("1 1 0 0 0 0 0 5 1 view_0.png\n\n")
    (sparse / "points3D.txt").write_text("")


def test_scene_yaml_errors(tmp_path, tiny_scene):
    with pytest.raises(SceneError, match="scene directory does not exist"):
        load_scene(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(SceneError, match="scene.yaml: missing"):
        load_scene(tmp_path / "empty")
    (tiny_scene / "scene.yaml").write_text("segments: [unclosed\n")
    with pytest.raises(SceneError, match="is not valid YAML"):
        load_scene(tiny_scene)


def test_mesh_errors(tiny_scene):
    ply = tiny_scene / "meshes/block.ply"
    data = ply.read_bytes()
    ply.unlink()
    with pytest.raises(SceneError, match="block.ply: mesh file missing"):
        load_scene(tiny_scene)
    ply.write_bytes(b"not a ply file")
    with pytest.raises(SceneError, match="block.ply: no triangles"):
        load_scene(tiny_scene)
    from framework.scene.write import write_mesh
    write_mesh(ply, np.zeros((3, 3)), np.zeros((0, 3), int))
    with pytest.raises(SceneError, match="block.ply: no triangles"):
        load_scene(tiny_scene)
    write_mesh(ply, [[0, 0, 0], [1, 0, np.nan], [0, 1, 0]], [[0, 1, 2]])
    with pytest.raises(SceneError, match="block.ply: vertices with NaN/Inf"):
        load_scene(tiny_scene)
    ply.write_bytes(data)
    load_scene(tiny_scene)


def test_segment_errors(tiny_scene):
    edit_scene_yaml(tiny_scene, lambda d: d["segments"][1].update(meshes=[]))
    with pytest.raises(SceneError, match="segment 'block' has no meshes"):
        load_scene(tiny_scene)
    edit_scene_yaml(tiny_scene, lambda d: d["segments"][1].update(meshes=["meshes/ground.ply"]))
    with pytest.raises(SceneError, match="meshes/ground.ply is in segments 'ground' and 'block'"):
        load_scene(tiny_scene)
    edit_scene_yaml(tiny_scene, lambda d: d["segments"][1].update(meshes=["meshes/block.ply"], kernels=["glossy"]))
    with pytest.raises(SceneError, match="unknown kernel 'glossy'"):
        load_scene(tiny_scene)


def test_reference_errors(tiny_scene):
    edit_scene_yaml(tiny_scene, lambda d: d["segments"][0]["reference"].update(diffuse=[0.5, 1.2, 0.3]))
    with pytest.raises(SceneError, match=r"reference diffuse = \[0.5, 1.2, 0.3\] is outside \[0, 1\]"):
        load_scene(tiny_scene)
    edit_scene_yaml(tiny_scene, lambda d: d["segments"][0]["reference"].update(diffuse=[0.5, 0.3]))
    with pytest.raises(SceneError, match="reference diffuse has 2 values; give one number or 3"):
        load_scene(tiny_scene)


def test_colmap_errors(tiny_scene):
    import shutil
    shutil.rmtree(tiny_scene / "sparse")
    with pytest.raises(SceneError, match="sparse: missing COLMAP model"):
        load_scene(tiny_scene)
    _write_one_camera(tiny_scene / "sparse", "OPENCV_FISHEYE 16 16 12 12 8 8 0 0 0 0")
    with pytest.raises(SceneError, match="is OPENCV_FISHEYE, a fisheye model"):
        load_scene(tiny_scene)


def test_image_errors(tiny_scene):
    _images(tiny_scene, skip=("view_1",))
    with pytest.raises(SceneError, match="view_1.exr: missing EXR file"):
        load_scene(tiny_scene)
    _images(tiny_scene, shape=(16, 12, 3))
    with pytest.raises(SceneError, match="image is 12x16, its camera is 16x16"):
        load_scene(tiny_scene)
    _images(tiny_scene, shape=(16, 16, 1), names=("Y",))
    with pytest.raises(SceneError, match=r"1 channel\(s\); this scene needs R,G,B"):
        load_scene(tiny_scene)
    _images(tiny_scene, value=np.nan)
    with pytest.raises(SceneError, match="NaN/Inf/negative values"):
        load_scene(tiny_scene)
    _images(tiny_scene, value=-0.1)
    with pytest.raises(SceneError, match="NaN/Inf/negative values"):
        load_scene(tiny_scene)


def test_variant_errors():
    from framework.render.backend import set_variant
    with pytest.raises(ConfigError, match="variant=llvm_ad_rgbx is not a Mitsuba variant"):
        set_variant("llvm_ad_rgbx")
    with pytest.raises(ConfigError, match="does not match the scene's channels Y"):
        set_variant("llvm_ad_rgb", channels=("Y",))


def test_libllvm_errors(tmp_path, monkeypatch):
    from framework.render.backend import ensure_libllvm
    old = tmp_path / "libLLVM-15.so.1"
    old.write_bytes(b"")
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(old))
    with pytest.raises(EnvironmentSetupError, match="is LLVM 15, Dr.Jit 1.5 aborts with it"):
        ensure_libllvm()
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(tmp_path / "missing.so"))
    with pytest.raises(EnvironmentSetupError, match="does not exist: install a libLLVM >= 16"):
        ensure_libllvm()
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH")
    monkeypatch.setattr("framework.render.backend.find_libllvm", lambda: None)
    with pytest.raises(EnvironmentSetupError, match="no libLLVM >= 16 found"):
        ensure_libllvm()
