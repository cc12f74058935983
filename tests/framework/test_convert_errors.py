"""Bad input to ``python -m framework.convert``: one line ``error: ...`` on stderr, exit status 2,
nothing written (the output folder, and no staging folder beside it); warnings are one line each.

Run in-process through :func:`framework.convert.__main__.main` (argparse and all)."""
from __future__ import annotations


import json

import numpy as np
import pytest
import yaml

from convert_inputs import (GROUND, ORIGIN, WALL, corner_cityjson, corner_glb, corner_obj, labelled_ply, obj_text,
                            write_delivery)
from framework.convert.__main__ import main


def _run(tmp_path, source, *extra, shift=(0.0, 0.0, 0.0), out=None):
    """(exit status, output folder) of converting ``source`` into ``out`` (default ``tmp_path/out``)."""
    d = write_delivery(tmp_path / "delivery", shift=shift)
    out = out or tmp_path / "out"
    return main([str(source), str(out), "--sparse", str(d["sparse"]), "--emitters", str(d["emitters"]), *extra]), out


def _error(tmp_path, capsys, source, *extra, match: str, **kw) -> str:
    status, out = _run(tmp_path, source, *extra, **kw)
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and err[0].startswith("error: "), err
    assert match in err[0], err[0]
    assert not out.exists() and not list(out.parent.glob(f".{out.name}.partial-*"))
    return err[0]


def _warnings(tmp_path, capsys, source, *extra, **kw) -> list[str]:
    status, out = _run(tmp_path, source, *extra, **kw)
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
    """The COLMAP model 5 km away from the mesh after the move: the blind-view check refuses it,
    pointing at the given model (not at OUT_DIR/sparse, never written, nor at a run's views=)."""
    d = tmp_path / "delivery" / "sparse"
    message = _error(tmp_path, capsys, corner_obj(tmp_path), shift=(5000.0, 0.0, 0.0),
                     match=f"no selected view sees any segment (corner.png see only sky or nothing): fix their "
                           f"poses in {d} (is the COLMAP model in the frame of corner.obj?)")
    assert "views=" not in message and "out/sparse" not in message


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


# ------------------------------------------------------------------------------------------------
# Odd survey inputs (issue 46): each once a traceback, a quiet wrong answer or a misleading line
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("option", ["--images", "--masks"])
def test_output_folder_inside_a_copied_folder(tmp_path, capsys, option):
    """OUT_DIR inside --images (or --masks): the copy would copy the staging folder into itself."""
    photos = tmp_path / "photos"
    photos.mkdir()
    (photos / "notes.txt").write_text("kept")
    _error(tmp_path, capsys, corner_obj(tmp_path), option, str(photos), out=photos / "scene",
           match=f"OUT_DIR {photos / 'scene'} is inside {option} {photos}")
    assert [p.name for p in photos.iterdir()] == ["notes.txt"]


def test_output_folder_inside_the_source_file(tmp_path, capsys):
    source = corner_obj(tmp_path)
    _error(tmp_path, capsys, source, out=source / "scene",
           match=f"OUT_DIR {source / 'scene'}: {source} is a file, not a folder")


@pytest.mark.parametrize("bowtie", [[[0, 0, 1], [3, 0, 3], [3, 0, 1], [0, 0, 2]],     # was one triangle
                                    [[0, 0, 1], [2, 0, 3], [2, 0, 1], [0, 0, 3]]])    # lobes cancel: was "degenerate"
def test_obj_self_intersecting_polygon(tmp_path, capsys, bowtie):
    """A bow-tie quad (its edges 1 and 3 cross) was triangulated into one triangle, a vertex
    dropped, silently (or, when its two lobes cancel, dropped as degenerate); it is refused with
    its line (12 vertex lines, then usemtl, f, usemtl, f, f)."""
    _error(tmp_path, capsys, corner_obj(tmp_path, wall=[WALL, bowtie]),
           match="material 'wall': line 17: the polygon crosses itself (its edges 1 and 3 cross)")


def test_cityjson_negative_semantic_index(tmp_path, capsys):
    """values [0, -1] read the last surface (Python indexing): refused as an index past the end is."""
    source = corner_cityjson(tmp_path)
    doc = json.loads(source.read_text())
    doc["CityObjects"]["house"]["geometry"][0]["semantics"]["values"] = [0, -1]
    source.write_text(json.dumps(doc))
    _error(tmp_path, capsys, source, match="CityObject 'house': surface [1] has the semantic value -1, not an "
                                           "index of its 2 semantic surfaces (0..1) or null")


def test_cityjson_negative_material_index(tmp_path, capsys):
    source = corner_cityjson(tmp_path)
    doc = json.loads(source.read_text())
    doc["appearance"] = {"materials": [{"name": "render"}, {"name": "glass"}]}
    doc["CityObjects"]["ground"]["geometry"][0]["material"] = {"paint": {"value": 0}}
    doc["CityObjects"]["house"]["geometry"][0]["material"] = {"paint": {"values": [0, -1]}}
    source.write_text(json.dumps(doc))
    _error(tmp_path, capsys, source, "--group", "material",
           match="CityObject 'house': surface [1] has the material value -1, not an index of its 2 appearance "
                 "materials (0..1) or null")


def test_ply_self_intersecting_polygon(tmp_path, capsys):
    source = labelled_ply(tmp_path, {0: "ground", 1: "wall"})
    source.write_text(source.read_text().replace("4 4 5 6 7 1", "4 4 6 5 7 1"))       # the wall's quad, crossed
    _error(tmp_path, capsys, source, match="label 'wall': face 1: the polygon crosses itself (its edges 1 and 3 cross)")


def test_hole_crossing_the_outer_ring():
    """A hole that crosses the outer ring of its surface is refused, naming both edges."""
    from framework.convert.model import Polygon, Source, triangulate
    from framework.errors import SceneError

    v = np.array([[0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0], [1, 1, 0], [5, 1, 0], [5, 2, 0], [1, 2, 0]], float)
    source = Source("street.city.json", "CityJSON", v, {})
    source.part("b1/WallSurface", "WallSurface", "surface").polygons.append(Polygon([np.arange(4), np.arange(4, 8)]))
    with pytest.raises(SceneError, match=r"surface 'b1/WallSurface': a polygon crosses itself \(its "
                                         r"edge 2 and hole 1's edge 1 cross\)"):
        triangulate(source)


def test_obj_material_names_not_utf8(tmp_path, capsys):
    """'usemtl b\\xe9ton' and 'usemtl b\\xe8ton' (Latin-1) merged into one segment 'b\\ufffdton'."""
    source = tmp_path / "corner.obj"
    text = obj_text({"ground": [GROUND], "betonA": [WALL], "betonB": [[[0, 0, 0], [1, 0, 0], [0, 1, 0]]]})
    source.write_bytes(text.encode().replace(b"betonA", b"b\xe9ton").replace(b"betonB", b"b\xe8ton"))
    _error(tmp_path, capsys, source, match="line 14: the material name b'b\\xe9ton' is not UTF-8")


def test_cityjson_duplicate_object_id(tmp_path, capsys):
    """A second 'house' silently replaced the first (json keeps the last key)."""
    source = corner_cityjson(tmp_path)
    doc = json.loads(source.read_text())
    objects = doc.pop("CityObjects")
    pairs = [json.dumps(k) + ": " + json.dumps(v) for k, v in [*objects.items(), ("house", objects["ground"])]]
    source.write_text(json.dumps(doc)[:-1] + ', "CityObjects": {' + ", ".join(pairs) + "}}")
    _error(tmp_path, capsys, source, match="CityObject id 'house' appears twice in CityObjects")


def test_gltf_float32_survey_coordinates_warned(tmp_path, capsys):
    """glTF positions are float32: at 6.9e6 m they are 0.5 m apart, and the converter says so."""
    warnings = _warnings(tmp_path, capsys, corner_glb(tmp_path))
    assert len(warnings) == 1 and "float32 positions at 6.9e+06 m are 0.5 m apart (errors up to 0.25 m)" in warnings[0]
    assert "'geom0'" in warnings[0] and "'geom1'" in warnings[0]


def test_gltf_local_positions_not_warned(tmp_path, capsys):
    assert _warnings(tmp_path, capsys, corner_glb(tmp_path, origin=np.zeros(3)), shift=-ORIGIN) == []


def test_obj_face_index_zero(tmp_path, capsys):
    (tmp_path / "bad.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\nf 0 1 2\n")
    _error(tmp_path, capsys, tmp_path / "bad.obj",
           match="line 6: face vertex index 0 out of range (1..3); OBJ indices start at 1")


def test_cityjson_version_as_a_number(tmp_path, capsys):
    _error(tmp_path, capsys, corner_cityjson(tmp_path, version=2.0),
           match="'version' is the number 2.0; CityJSON writes it as a string: \"version\": \"2.0\"")


def test_kernels_literal_name_before_patterns(tmp_path, capsys):
    """'Glass [clear]' names a segment literally (as a shell pattern [clear] is one letter), and the
    literal entry wins over an earlier pattern that also matches."""
    source = corner_obj(tmp_path, **{"Glass [clear]": [[[0, 10, 2], [1, 10, 2], [1, 10, 3], [0, 10, 3]]]})
    assert _warnings(tmp_path, capsys, source, "--kernels", "*=diffuse", "Glass [clear]=diffuse,specular") == []
    segments = yaml.safe_load((tmp_path / "out" / "scene.yaml").read_text())["segments"]
    assert {s["name"]: s["kernels"] for s in segments} == {
        "ground": ["diffuse"], "wall": ["diffuse"], "Glass [clear]": ["diffuse", "specular"]}


def test_kernels_pattern_for_no_segment_says_how_to_match_literally(tmp_path, capsys):
    _error(tmp_path, capsys, corner_obj(tmp_path), "--kernels", "wall [old]=diffuse",
           match="'[...]' in a pattern is a set of characters: write [[] for a literal '['")


def test_obj_nan_vertex(tmp_path, capsys):
    source = corner_obj(tmp_path)
    lines = source.read_text().splitlines()
    source.write_text("\n".join(["v nan 4 8", *lines[1:]]) + "\n")
    _error(tmp_path, capsys, source, match="line 1: vertex 1 ('v nan 4 8') has a NaN or infinite coordinate; fix it")


def test_obj_tabs_between_keyword_and_values(tmp_path, capsys):
    """'f<TAB>5 6 7 8' was skipped (the material then 'has no faces'); tabs separate as spaces do."""
    source = corner_obj(tmp_path)
    text = source.read_text()
    source.write_text(text.replace("f 5 6 7 8", "f\t5 6 7 8").replace("usemtl wall", "usemtl\twall"))
    assert _warnings(tmp_path, capsys, source) == []
    segments = yaml.safe_load((tmp_path / "out" / "scene.yaml").read_text())["segments"]
    assert [s["name"] for s in segments] == ["ground", "wall"]


def test_survey_mesh_with_a_local_colmap_model(tmp_path, capsys):
    """A survey OBJ and a COLMAP model in a local frame: refused before anything is written, with
    the fix on the converter's side (no OUT_DIR/sparse, no views=)."""
    message = _error(tmp_path, capsys, corner_obj(tmp_path), shift=-ORIGIN,
                     match="every camera lies within 1 km of 0 (a local frame) while corner.obj is in survey "
                           "coordinates (origin [652340.000, 6862275.000, 35.000])")
    assert "views=" not in message and "out/sparse" not in message
