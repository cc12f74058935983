"""Bad input to ``python -m framework.convert``: one line ``error: ...`` on stderr, exit status 2,
nothing written (the output folder, and no staging folder beside it); warnings are one line each.

Run in-process through :func:`framework.convert.__main__.main` (argparse and all)."""
from __future__ import annotations


import numpy as np
import yaml

from convert_inputs import GROUND, WALL, corner_cityjson, corner_obj, labelled_ply, obj_text, write_delivery
from framework.convert.__main__ import main


def _run(tmp_path, source, *extra, shift=(0.0, 0.0, 0.0)):
    """(exit status, stderr lines, output folder) of converting ``source``."""
    d = write_delivery(tmp_path / "delivery", shift=shift)
    out = tmp_path / "out"
    return main([str(source), str(out), "--sparse", str(d["sparse"]), "--emitters", str(d["emitters"]), *extra]), out


def _error(tmp_path, capsys, source, *extra, match: str, **kw) -> str:
    status, out = _run(tmp_path, source, *extra, **kw)
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and err[0].startswith("error: "), err
    assert match in err[0], err[0]
    assert not out.exists() and not list(tmp_path.glob(".out.partial-*"))
    return err[0]


def _warnings(tmp_path, capsys, source, *extra) -> list[str]:
    status, out = _run(tmp_path, source, *extra)
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 0 and (out / "scene.yaml").is_file(), err
    return [line for line in err if line.startswith("warning: ")]


def test_missing_source(tmp_path, capsys):
    _error(tmp_path, capsys, tmp_path / "nothing.obj", match="nothing.obj: no such file")


def test_empty_source(tmp_path, capsys):
    (tmp_path / "empty.obj").write_text("")
    _error(tmp_path, capsys, tmp_path / "empty.obj", match="empty.obj: is empty")


def test_unknown_format(tmp_path, capsys):
    (tmp_path / "street.dxf").write_text("0\nSECTION\n")
    _error(tmp_path, capsys, tmp_path / "street.dxf", match="unknown format '.dxf'")


def test_obj_without_faces(tmp_path, capsys):
    (tmp_path / "points.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    _error(tmp_path, capsys, tmp_path / "points.obj", match="no faces with an area")


def test_obj_face_index_out_of_range(tmp_path, capsys):
    (tmp_path / "bad.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 7\n")
    _error(tmp_path, capsys, tmp_path / "bad.obj", match="face vertex index 7 out of range (1..3)")


def test_material_without_faces_is_a_warning(tmp_path, capsys):
    source = tmp_path / "corner.obj"
    source.write_text(obj_text({"ground": [GROUND], "wall": [WALL]}) + "usemtl paint\n")
    warnings = _warnings(tmp_path, capsys, source)
    assert warnings == [f"warning: {source}: material 'paint' has no faces; it gets no segment"]


def test_degenerate_polygons_dropped_with_a_count(tmp_path, capsys):
    """Degenerate faces are dropped (not refused) and counted in one warning line."""
    line = [[0, 0, 0], [1, 0, 0], [2, 0, 0]]                              # collinear: no area
    source = corner_obj(tmp_path, wall=[WALL, line, [[0, 0, 1], [0, 0, 1], [1, 0, 1], [1, 0, 1]]])
    warnings = _warnings(tmp_path, capsys, source)
    assert len(warnings) == 1 and "dropped 2 degenerate face(s) or polygon(s)" in warnings[0]


def test_segment_of_degenerate_faces_only(tmp_path, capsys):
    source = corner_obj(tmp_path, kerb=[[[0, 0, 0], [1, 0, 0], [2, 0, 0]]])
    _error(tmp_path, capsys, source, match="material 'kerb': all its 1 faces are degenerate")


def test_cityjson_without_transform(tmp_path, capsys):
    _error(tmp_path, capsys, corner_cityjson(tmp_path, transform=False), match="no 'transform'")


def test_cityjson_unknown_version(tmp_path, capsys):
    _error(tmp_path, capsys, corner_cityjson(tmp_path, version="1.0"), match="CityJSON version '1.0' is not supported")


def test_cityjson_geometry_template_refused(tmp_path, capsys):
    _error(tmp_path, capsys, corner_cityjson(tmp_path, template=True),
           match="CityObject 'tree' uses a geometry template (GeometryInstance)")


def test_cityjson_not_json(tmp_path, capsys):
    (tmp_path / "x.city.json").write_text('{"type": "CityJSON",')
    _error(tmp_path, capsys, tmp_path / "x.city.json", match="is not valid JSON (line 1")


def test_cameras_far_from_the_geometry(tmp_path, capsys):
    """The COLMAP model 5 km away from the mesh after the move: the blind-view check refuses it."""
    _error(tmp_path, capsys, corner_obj(tmp_path), shift=(5000.0, 0.0, 0.0),
           match="no selected view sees any segment")


def test_ply_label_no_face_uses_is_a_warning(tmp_path, capsys):
    source = labelled_ply(tmp_path, {0: "ground", 1: "wall", 7: "roof"})
    warnings = _warnings(tmp_path, capsys, source)
    assert warnings == [f"warning: {tmp_path / 'corner.labels.yaml'}: label 7 (roof) is used by no face of "
                        f"{source}; it gets no segment"]


def test_ply_face_label_without_a_name(tmp_path, capsys):
    _error(tmp_path, capsys, labelled_ply(tmp_path, {0: "ground"}), match="face label 1 of")


def test_ply_without_label_table(tmp_path, capsys):
    source = labelled_ply(tmp_path, {0: "ground", 1: "wall"})
    (tmp_path / "corner.labels.yaml").unlink()
    _error(tmp_path, capsys, source, match="corner.labels.yaml: missing")


def test_kernels_for_no_segment(tmp_path, capsys):
    _error(tmp_path, capsys, corner_obj(tmp_path), "--kernels", "facade=diffuse,specular",
           match="--kernels facade=...: no segment of corner.obj is named so; segments: ground, wall")


def test_unknown_kernel(tmp_path, capsys):
    _error(tmp_path, capsys, corner_obj(tmp_path), "--default-kernels", "lambert", match="--default-kernels: ")


def test_group_semantic_on_obj(tmp_path, capsys):
    _error(tmp_path, capsys, corner_obj(tmp_path), "--group", "semantic",
           match="--group semantic does not apply to OBJ (corner.obj); use material or object")


def test_output_folder_not_empty(tmp_path, capsys):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "keep.txt").write_text("mine")
    status, _ = _run(tmp_path, corner_obj(tmp_path))
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "exists and is not an empty folder" in err[0]
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["keep.txt"]


def test_bad_emitters_named_in_their_file(tmp_path, capsys):
    d = write_delivery(tmp_path / "delivery")
    d["emitters"].write_text(yaml.safe_dump({"emitters": [{"type": "constant", "radiance": -1.0}]}))
    status = main([str(corner_obj(tmp_path)), str(tmp_path / "out"), "--sparse", str(d["sparse"]),
                   "--emitters", str(d["emitters"])])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1
    assert err[0].startswith(f"error: {d['emitters']}: emitter 0 (constant) radiance") and "negative" in err[0]
    assert not (tmp_path / "out").exists()



def test_photograph_of_the_wrong_size_named_in_images(tmp_path, capsys):
    """--images is checked as the loader checks images/; the message names the given folder."""
    from framework.images import write_exr

    (tmp_path / "photos").mkdir()
    write_exr(tmp_path / "photos" / "corner.exr", np.zeros((8, 8, 3), np.float32), ("R", "G", "B"))
    message = _error(tmp_path, capsys, corner_obj(tmp_path), "--images", str(tmp_path / "photos"),
                     match="corner.exr: image is 8x8, its camera is 16x16")
    assert message.startswith(f"error: {tmp_path / 'photos' / 'corner.exr'}"), message
