"""Bad scene folders, one way each: a SceneError whose message is one line naming the file and
the key (segment, emitter, image, line) and saying how to fix it; and what the loader reads
(image sub-folders, the file the poses come from, the content hash of every file read)."""
from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from factory import edit_scene_yaml, quad, scene_error_message

from framework.images import write_exr
from framework.scene import load_scene
from framework.scene.write import write_mesh


def _replace(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new))


_message = scene_error_message


def _set_fields(path: Path, match: dict[int, str], new: dict[int, str]) -> None:
    """Set fields of the one line of a COLMAP text file whose fields ``match`` (index -> text).

    Lines are found by their fields, never by a printed float: a computed pose prints other last
    digits on a CPU of another SIMD level."""
    lines = path.read_text().split("\n")
    hits = [i for i, line in enumerate(lines) if not line.startswith("#")
            and all(len(line.split()) > k and line.split()[k] == v for k, v in match.items())]
    assert len(hits) == 1, (match, hits)
    fields = lines[hits[0]].split()
    for k, v in new.items():
        fields[k] = v
    lines[hits[0]] = " ".join(fields)
    path.write_text("\n".join(lines))


def _tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _images(root: Path, names=("view_0", "view_1")) -> None:
    for name in names:
        (root / "images" / name).parent.mkdir(parents=True, exist_ok=True)
        write_exr(root / "images" / f"{name}.exr", np.full((16, 16, 3), 0.2, np.float32), ("R", "G", "B"))


# ----------------------------------------------------------------------------------------------
# scene.yaml: keys, types, names
# ----------------------------------------------------------------------------------------------

def test_segment_key_typo_is_refused(tiny_scene):
    """``kernel:`` instead of ``kernels:`` used to drop the specular kernel silently."""
    edit_scene_yaml(tiny_scene, lambda d: d["segments"][0].update(kernel=d["segments"][0].pop("kernels")))
    msg = _message(tiny_scene, r"segment 'ground': unknown key 'kernel' \(did you mean 'kernels'\?\); "
                               r"allowed keys: name, meshes, kernels, reference, known$")
    assert msg.startswith(str(tiny_scene / "scene.yaml"))


@pytest.mark.parametrize("edit, match", [
    (lambda d: d.update(segment=d.pop("segments")),
     r"scene.yaml: unknown key 'segment' \(did you mean 'segments'\?\); allowed keys: name, channels, "),
    (lambda d: d["emitters"][0].update(irradiance=1.0),
     r"emitter 0 \(constant\): unknown key 'irradiance' \(did you mean 'radiance'\?\); "
     r"allowed keys: type, radiance, scale$"),
    (lambda d: d["segments"][1]["reference"].update(glossy=0.1),
     r"segment 'block' reference: unknown key 'glossy'; allowed keys: diffuse, specular$"),
], ids=["top-level", "emitter", "reference"])
def test_unknown_keys_are_refused(tiny_scene, edit, match):
    edit_scene_yaml(tiny_scene, edit)
    _message(tiny_scene, match)


def test_key_given_twice_is_refused(tiny_scene):
    """PyYAML keeps the last of two equal keys; the loader refuses them."""
    _replace(tiny_scene / "scene.yaml", "  kernels: [diffuse, specular]\n  reference:\n    diffuse: [0.5",
             "  kernels: [diffuse, specular]\n  kernels: [diffuse]\n  reference:\n    diffuse: [0.5")
    _message(tiny_scene, r"scene.yaml: line 7 is not valid YAML \(key 'kernels' is given twice in one "
                         r"mapping, keep one\); fix the syntax$")


def test_duplicate_segment_names_are_refused(tiny_scene):
    edit_scene_yaml(tiny_scene, lambda d: d["segments"][1].update(name="ground"))
    _message(tiny_scene, r"scene.yaml: segments 0 and 1 are both named 'ground'; give each segment its own name")


def test_one_mesh_in_two_segments_through_two_spellings(tiny_scene):
    edit_scene_yaml(tiny_scene, lambda d: d["segments"][1].update(meshes=["./meshes/ground.ply"]))
    _message(tiny_scene, r"scene.yaml: mesh meshes/ground.ply is in segments 'ground' and 'block' \(as "
                         r"meshes/ground.ply and ./meshes/ground.ply: the same file\); a mesh belongs to one")


@pytest.mark.parametrize("kernels, match", [
    ([], r"segment 'ground' kernels is empty; list at least one kernel, e.g. \[diffuse\]"),
    (5, r"segment 'ground' kernels must be a list, e.g. \[diffuse\]; got 5$"),
    ("diffuse", r"segment 'ground' kernels must be a list, e.g. \[diffuse\]; got the string 'diffuse'$"),
], ids=["empty", "number", "string"])
def test_bad_kernels_value(tiny_scene, kernels, match):
    edit_scene_yaml(tiny_scene, lambda d: d["segments"][0].update(kernels=kernels, reference={"diffuse": 0.5}))
    _message(tiny_scene, match)


def test_segment_meshes_as_a_string(tiny_scene):
    edit_scene_yaml(tiny_scene, lambda d: d["segments"][0].update(meshes="meshes/ground.ply"))
    _message(tiny_scene, r"segment 'ground' meshes must be a list, e.g. \[meshes/ground.ply\]; got the "
                         r"string 'meshes/ground.ply'$")


def test_area_emitter_meshes_as_a_string(tiny_scene):
    edit_scene_yaml(tiny_scene, lambda d: d["emitters"].append(
        {"type": "area", "meshes": "meshes/block.ply", "radiance": 1.0}))
    _message(tiny_scene, r"emitter 2 \(area\) meshes must be a list, e.g. \[meshes/block.ply\]; got the string")


def test_emitters_as_a_string(tiny_scene):
    edit_scene_yaml(tiny_scene, lambda d: d.update(emitters="constant"))
    _message(tiny_scene, r"scene.yaml: emitters must be a list, e.g. \[\{type: constant, radiance: 1.0\}\]; "
                         r"got the string 'constant'$")


def test_envmap_scale_not_a_number(tiny_scene):
    edit_scene_yaml(tiny_scene, lambda d: d["emitters"].append({"type": "envmap", "file": "sky.exr", "scale": "bright"}))
    _message(tiny_scene, r"emitter 2 \(envmap\) scale 'bright' is neither a number nor the word unknown; give a "
                         r"number >= 0 \(it multiplies the light\), or unknown to estimate it$")


@pytest.mark.parametrize("emitter, match", [
    ({"type": "constant", "radiance": [0.3, -0.35, 0.45]},
     r"emitter 2 \(constant\) radiance = \[0.3, -0.35, 0.45\] is negative; light is >= 0"),
    ({"type": "directional", "direction": [0, 0, -1], "irradiance": -3.0},
     r"emitter 2 \(directional\) irradiance = \[-3.0, -3.0, -3.0\] is negative; light is >= 0"),
    ({"type": "envmap", "file": "sky.exr", "scale": -1},
     r"emitter 2 \(envmap\) scale = -1 must be finite and >= 0"),
], ids=["radiance", "irradiance", "envmap-scale"])
def test_negative_light_is_refused(tiny_scene, emitter, match):
    edit_scene_yaml(tiny_scene, lambda d: d["emitters"].append(emitter))
    _message(tiny_scene, match)


def test_reference_sum_above_one(tiny_scene):
    edit_scene_yaml(tiny_scene, lambda d: d["segments"][1]["reference"].update(specular=[0.2, 0.5, 0.2]))
    _message(tiny_scene, r"segment 'block' reference: diffuse \+ specular = 1.1 > 1 in channel G; a segment's "
                         r"weights sum to at most 1 per channel \(energy conservation\)")


# ----------------------------------------------------------------------------------------------
# Meshes
# ----------------------------------------------------------------------------------------------

def test_segment_of_zero_area(tiny_scene):
    collinear = [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]]
    write_mesh(tiny_scene / "meshes/block.ply", collinear, [[0, 1, 2], [1, 2, 3]])
    _message(tiny_scene, r"scene.yaml: segment 'block': all 2 triangles of meshes/block.ply have zero area; "
                         r"fix the mesh$")


@pytest.mark.parametrize("keep, match", [
    (500, r"block.ply: corrupt or truncated PLY \(RPly: Error reading value number 1 of 'vertex_indices' of "
          r"'face' number 8\); re-export the mesh$"),
    (300, r"block.ply: no triangles \(unreadable or empty PLY: RPly: Error reading 'x' of 'vertex' number 4\)"),
], ids=["in-faces", "in-vertices"])
def test_truncated_ply_prints_nothing_else(tiny_scene, capfd, keep, match):
    """Open3D's reader (RPly) prints its own error on the C stderr: the loader keeps it quiet."""
    ply = tiny_scene / "meshes/block.ply"
    ply.write_bytes(ply.read_bytes()[:keep])
    capfd.readouterr()
    _message(tiny_scene, match)
    out, err = capfd.readouterr()
    assert out == "" and err == ""


@pytest.mark.slow
def test_cli_prints_one_line_for_a_truncated_ply(tiny_scene, tmp_path):
    ply = tiny_scene / "meshes/block.ply"
    ply.write_bytes(ply.read_bytes()[:500])
    before = _tree(tiny_scene)
    run_dir = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "framework.run", f"scene.dir={tiny_scene}",
                           f"hydra.run.dir={run_dir}", f"cache.dir={tmp_path / 'c'}"], cwd=tmp_path,
                          env=dict(os.environ, HYDRA_FULL_ERROR="0"), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2
    assert proc.stderr.splitlines() == [f"error: {ply}: corrupt or truncated PLY (RPly: Error reading value "
                                        "number 1 of 'vertex_indices' of 'face' number 8); re-export the mesh"]
    assert not (run_dir / "results.json").exists() and _tree(tiny_scene) == before


# ----------------------------------------------------------------------------------------------
# The COLMAP model
# ----------------------------------------------------------------------------------------------

CAMERA_1 = {0: "1", 1: "PINHOLE"}               # cameras.txt: CAMERA_ID MODEL WIDTH HEIGHT PARAMS...
VIEW = {9: "view_0.png"}                         # images.txt: IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME


@pytest.mark.parametrize("file, match, new, message", [
    ("cameras.txt", CAMERA_1, {4: "-59.7", 5: "-59.7"},
     r"cameras.txt: camera 1 \(of image view_0.png\) has focal length -59.7, -59.7; focal lengths are > 0"),
    ("cameras.txt", CAMERA_1, {2: "0"},
     r"cameras.txt: camera 1 \(of image view_0.png\) is 0x16 pixels; give its WIDTH and HEIGHT \(> 0\)$"),
    ("cameras.txt", CAMERA_1, {3: "0"},
     r"cameras.txt: camera 1 \(of image view_0.png\) is 16x0 pixels; give its WIDTH and HEIGHT \(> 0\)$"),
    ("images.txt", VIEW, {8: "7"},
     r"images.txt: line 5: image view_0.png uses camera 7, which cameras.txt does not define; add the "
     r"camera or fix the image's CAMERA_ID$"),
    ("images.txt", {9: "view_1.png"}, {0: "1"},
     r"images.txt: line 7: image id 1 \(view_1.png\) is already used on line 5 \(view_0.png\); list each "
     r"image once, with its own IMAGE_ID$"),
], ids=["negative-focal", "zero-width", "zero-height", "camera-missing", "image-id-twice"])
def test_colmap_text_errors(tiny_scene, file, match, new, message):
    _set_fields(tiny_scene / "sparse" / file, match, new)
    _message(tiny_scene, message)


def test_image_listed_twice(tiny_scene):
    images = tiny_scene / "sparse/images.txt"
    first = next(line for line in images.read_text().splitlines() if line.endswith("view_0.png"))
    images.write_text(images.read_text() + "3" + first[1:] + "\n\n")
    _message(tiny_scene, r"images.txt: image 'view_0.png' is listed twice; list each image once$")


def test_image_without_points_line(tiny_scene):
    """pycolmap drops an image whose second line is missing; the loader says so."""
    images = tiny_scene / "sparse/images.txt"
    images.write_text(images.read_text().rstrip("\n") + "\n")
    _message(tiny_scene, r"images.txt: line 7: image view_1.png has no second line")


def test_frames_without_rigs(tiny_scene):
    (tiny_scene / "sparse/rigs.txt").unlink()
    _message(tiny_scene, r"frames.txt: present without rigs.txt; pycolmap reads the two together")


def test_image_in_no_frame(tiny_scene):
    (tiny_scene / "sparse/images.txt").write_text(
        (tiny_scene / "sparse/images.txt").read_text() + "3 1 0 0 0 0 0 5 1 view_2.png\n\n")
    _message(tiny_scene, r"images.txt: line 9: image 3 \(view_2.png\) is in no frame of frames.txt; add it "
                         r"there, or delete frames.txt and rigs.txt")


def test_images_txt_disagrees_with_frames_txt(tiny_scene):
    """pycolmap takes the poses from frames.txt: an edit of images.txt alone is refused."""
    _set_fields(tiny_scene / "sparse/images.txt", VIEW, {7: "9.5"})
    msg = _message(tiny_scene, r"images.txt \(line 5\) and .*frames.txt give image view_0.png different "
                               r"poses; pycolmap takes the pose from frames.txt")
    assert str(tiny_scene / "sparse/frames.txt") in msg


def test_pose_source_is_recorded(tiny_scene, caplog):
    with caplog.at_level(logging.INFO, logger="framework.scene.colmap"):
        scene = load_scene(tiny_scene)
    assert scene.pose_source == "sparse/frames.txt"
    assert "camera poses read from sparse/frames.txt" in caplog.text
    (tiny_scene / "sparse/frames.txt").unlink()
    (tiny_scene / "sparse/rigs.txt").unlink()
    _set_fields(tiny_scene / "sparse/images.txt", VIEW, {7: "9.5"})
    scene = load_scene(tiny_scene)
    assert scene.pose_source == "sparse/images.txt"
    assert scene.camera("view_0.png").cam_from_world[2, 3] == 9.5


# ----------------------------------------------------------------------------------------------
# Image names
# ----------------------------------------------------------------------------------------------

def test_image_name_with_a_sub_folder_is_read(tiny_scene):
    _replace(tiny_scene / "sparse/images.txt", " view_0.png", " left/top_000.png")
    _images(tiny_scene, names=("left/top_000", "view_1"))
    scene = load_scene(tiny_scene)
    assert set(scene.images) == {"left/top_000.png", "view_1.png"}


@pytest.mark.parametrize("name", ["../top_000.png", "left/../../top_000.png", "/top_000.png"])
def test_image_name_leaving_the_folder(tiny_scene, name):
    _replace(tiny_scene / "sparse/images.txt", " view_0.png", f" {name}")
    _message(tiny_scene, rf"images.txt: image name '{name}' leaves the scene folder \(absolute or '..'\); "
                         r"name images by paths inside images/")


# ----------------------------------------------------------------------------------------------
# What is read: never written, all hashed
# ----------------------------------------------------------------------------------------------

def test_failed_load_leaves_the_folder_untouched(tiny_scene):
    edit_scene_yaml(tiny_scene, lambda d: d["segments"][0].update(kernels="diffuse"))
    before = _tree(tiny_scene)
    _message(tiny_scene, "must be a list")
    assert _tree(tiny_scene) == before


def test_content_hash_covers_meshes_outside_the_folder(tiny_scene):
    outside = tiny_scene.parent / "outside"
    write_mesh(outside / "x.ply", *quad(-1, 1, -1, 1, z=3.0))
    edit_scene_yaml(tiny_scene, lambda d: d["emitters"].append({"type": "area", "meshes": ["../outside/x.ply"],
                                                       "radiance": 1.0}))
    h0 = load_scene(tiny_scene).content_hash
    (tiny_scene / "notes.txt").write_text("not read by the loader")
    assert load_scene(tiny_scene).content_hash == h0
    write_mesh(outside / "x.ply", *quad(-1, 1, -1, 1, z=3.5))
    assert load_scene(tiny_scene).content_hash != h0


def test_content_hash_follows_symlinked_folders(tiny_scene):
    real = tiny_scene.parent / "real_meshes"
    (tiny_scene / "meshes").rename(real)
    (tiny_scene / "meshes").symlink_to(real, target_is_directory=True)
    h0 = load_scene(tiny_scene).content_hash
    write_mesh(real / "ground.ply", *quad(-5, 5, -5, 4))
    assert load_scene(tiny_scene).content_hash != h0


def test_content_hash_does_not_depend_on_the_folder_location(tiny_scene):
    h0 = load_scene(tiny_scene).content_hash
    moved = tiny_scene.rename(tiny_scene.parent / "elsewhere")
    assert load_scene(moved).content_hash == h0



def test_environment_images_of_different_sizes(tiny_scene):
    """Mitsuba renders one environment per scene, so several are summed texel by texel into one
    image: two envmaps of different sizes are refused in one line before anything renders (the
    scene still loads: a tool may read it), not by a traceback or a silent resampling."""
    from factory import compose_config

    from framework.errors import SceneError
    from framework.experiment import prepare
    from framework.images import write_exr
    from framework.scene import load_scene
    write_exr(tiny_scene / "a.exr", np.full((4, 8, 3), 0.2, np.float32))
    write_exr(tiny_scene / "b.exr", np.full((8, 16, 3), 0.1, np.float32))
    edit_scene_yaml(tiny_scene, lambda d: d["emitters"].extend([{"type": "envmap", "file": "a.exr"},
                                                                 {"type": "envmap", "file": "b.exr"}]))
    assert len(load_scene(tiny_scene).emitters) == 4
    with pytest.raises(SceneError, match=r"scene.yaml: emitters 2 and 3 are environment images of different sizes "
                                         r"\(8x4 and 16x8\); Mitsuba renders one environment, so they are summed "
                                         r"texel by texel: resample one to the other's size") as info:
        prepare(compose_config(tiny_scene, "views=all"))
    assert "\n" not in str(info.value)
