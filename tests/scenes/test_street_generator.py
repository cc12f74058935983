"""The street generator (:mod:`scenes.street_block`): urban_canyon cut into K buildings per side.

Deterministic bytes, one segment per building element, references with ρ_d + ρ_s ≤ 1, clipping
that keeps every triangle's area and winding, K = 1 equal to urban_canyon's geometry, the
bundled ``street_block`` up to date, and a symbolic run on an 18-material street.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

import files
from factory import run_street_cli
from framework.scene import load_scene
from scenes import BUNDLED_DIR
from scenes import build as scene_build
from scenes import geometry as g
from scenes import street_block as sb
from scenes import urban_canyon as uc

#: Materials per K: 8 K + 2, less the buildings without a balcony (none of the five
#: balconies per side reaches them: 2 per side at K = 8, 8 per side at K = 16).
MATERIALS = {1: 10, 2: 18, 4: 34, 8: 62, 16: 114}


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _segments(folder: Path) -> list[dict]:
    return yaml.safe_load((folder / "scene.yaml").read_text())["segments"]


def _area_vector(mesh: g.Mesh) -> np.ndarray:
    """Σ of the triangles' area vectors (normal × area): kept by a cut that keeps the windings."""
    v, f = mesh
    return 0.5 * np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]).sum(axis=0)


def _area(mesh: g.Mesh) -> float:
    v, f = mesh
    return 0.5 * float(np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum())


@pytest.fixture(scope="module")
def street4(tmp_path_factory) -> Path:
    """K = 4 buildings per side, 32 x 32 views."""
    return sb.build(tmp_path_factory.mktemp("street") / "street4", buildings=4, image=32)


@pytest.mark.slow
def test_same_seed_same_bytes_other_seed_other_materials(tmp_path, street4):
    again = sb.build(tmp_path / "street4", buildings=4, image=32)
    assert _files(again) == _files(street4)
    other = sb.build(tmp_path / "other", buildings=4, seed=1, image=32)
    a, b = _files(street4), _files(other)
    assert [k for k in a if a[k] != b[k]] == ["scene.yaml"]
    refs = lambda f: {s["name"]: s["reference"] for s in _segments(f)}
    changed = [n for n, r in refs(street4).items() if r != refs(other)[n]]
    assert set(changed) == {s["name"] for s in _segments(street4)} - {"roof", "asphalt"}


@pytest.mark.parametrize("buildings", sorted(MATERIALS))
def test_segment_count_and_names(buildings):
    segments = sb.building_meshes(buildings)
    assert len(segments) == MATERIALS[buildings]
    expected = {f"{side}{k:02d}_{e}" for _, side in uc.SIDES for k in range(buildings) for e in sb.ELEMENTS}
    assert set(segments) - {"roof", "asphalt"} <= expected
    assert {n for n in expected if n not in segments} <= {n for n in expected if n.endswith("_balcony")}
    assert list(segments)[-2:] == ["roof", "asphalt"]
    stems = [stem for parts in segments.values() for stem, _ in parts]
    assert len(stems) == len(set(stems))
    assert all(len(m[1]) > 0 for parts in segments.values() for _, m in parts)


def test_every_mesh_in_one_segment_and_folder_loads(street4):
    segments = _segments(street4)
    assert len(segments) == MATERIALS[4]
    meshes = [m for s in segments for m in s["meshes"]]
    assert len(meshes) == len(set(meshes))
    assert {str(p.relative_to(street4)) for p in street4.glob("meshes/*.ply")} == set(meshes)
    assert all(s["kernels"] == ["diffuse", "specular"] for s in segments)
    scene = load_scene(street4)
    assert [s.name for s in scene.segments] == [s["name"] for s in segments]
    assert [c.name for c in scene.cameras] == ["aerial_000.png"] + [f"street_{i:03d}.png" for i in range(8)]
    assert all((c.width, c.height) == (32, 32) for c in scene.cameras)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_references_in_range_and_energy_conserving(seed):
    refs = sb.references(16, seed)
    assert len(refs) == 2 * 16 * len(sb.ELEMENTS) + 2
    for name, ref in refs.items():
        d, s = np.asarray(ref["diffuse"], float), float(ref["specular"])
        assert d.shape == (3,) and (d >= 0).all() and 0 <= s <= 1, name
        assert (d + s <= 1 + 1e-12).all(), name
    windows = [r["specular"] for n, r in refs.items() if n.endswith("_window")]
    walls = [r["specular"] for n, r in refs.items() if n.endswith("_wall")]
    assert min(windows) >= sb.MATERIALS["window"][2][0] and max(walls) <= sb.MATERIALS["wall"][2][1]
    assert len({tuple(r["diffuse"]) for r in refs.values()}) == len(refs)


def test_references_do_not_depend_on_which_elements_exist():
    """Building k's materials come from its own generator: the same at every call."""
    assert sb.references(2, 5)["south01_wall"] == sb.references(2, 5)["south01_wall"]
    assert sb.references(2, 5)["north00_window"] == sb.references(4, 5)["north00_window"]


def test_split_keeps_area_and_winding():
    tri = (np.array([[-1.0, 0, 0], [2.0, 0, 0], [0.0, 1, 0]]), np.array([[0, 1, 2]]))
    below, above = sb.split_x(tri, 0.5)
    assert _area(below) + _area(above) == pytest.approx(_area(tri))
    np.testing.assert_allclose(_area_vector(below) + _area_vector(above), _area_vector(tri))
    assert below[0][:, 0].max() <= 0.5 and above[0][:, 0].min() >= 0.5
    for part in (below, above):
        assert (g.face_normals(part)[:, 2] > 0).all()
    face = g.quad([1.0, 0, 0], [0, 0, 1], [0, 1, 0])          # in the plane x = 1, normal -x
    below, above = sb.split_x(face, 1.0)
    assert len(below[1]) == 0 and len(above[1]) == 2
    below, above = sb.split_x(g.flip(face), 1.0)
    assert len(below[1]) == 2 and len(above[1]) == 0


@pytest.mark.parametrize("buildings", [2, 4, 8, 16])
def test_strips_partition_every_element(buildings):
    edges = sb.building_edges(buildings)
    for side, _ in uc.SIDES:
        for name, mesh in uc.side_meshes(side).items():
            parts = sb.strips(mesh, buildings)
            assert len(parts) == buildings
            assert sum(_area(p) for p in parts) == pytest.approx(_area(mesh)), name
            np.testing.assert_allclose(sum(_area_vector(p) for p in parts), _area_vector(mesh), atol=1e-6)
            for (lo, hi), (v, f) in zip(zip(edges[:-1], edges[1:]), parts):
                assert len(f) == 0 or (v[:, 0].min() >= lo - 1e-9 and v[:, 0].max() <= hi + 1e-9)


def test_one_building_is_urban_canyon(tmp_path):
    """K = 1: urban_canyon's own mesh files, sky and cameras, one material per element and side."""
    folder = sb.build(tmp_path / "k1", buildings=1)
    canyon = BUNDLED_DIR / "urban_canyon"
    for _, side in uc.SIDES:
        for element in (*sb.ELEMENTS, "roof"):
            ours = folder / f"meshes/{side}00_{element}.ply"
            assert files.file_difference(ours, canyon / f"meshes/{element}_{side}.ply") is None, ours
    for same in ("meshes/asphalt.ply", "sky.exr", *(f"sparse/{p.name}" for p in (canyon / "sparse").iterdir())):
        assert files.file_difference(folder / same, canyon / same) is None, same
    emitters = lambda f: yaml.safe_load((f / "scene.yaml").read_text())["emitters"]
    assert emitters(folder) == emitters(canyon)


def test_bundled_street_block_is_up_to_date(tmp_path):
    out = scene_build.build("street_block", tmp_path, preview=False)
    bundled = {k: v for k, v in _files(BUNDLED_DIR / "street_block").items() if k != "preview.png"}
    assert bundled == _files(out)
    assert len(_segments(out)) == MATERIALS[2]
    size = sum(p.stat().st_size for p in (BUNDLED_DIR / "street_block").rglob("*") if p.is_file())
    assert size < 2_000_000
    conf = yaml.safe_load((Path(__file__).resolve().parents[2] / "framework/conf/scene/street_block.yaml").read_text())
    assert conf == {"name": "street_block", "dir": None, "views": "all"}


@pytest.mark.slow
def test_symbolic_run_on_18_materials(tmp_path):
    """``python -m framework.run`` on K = 2 (18 materials, D = 36; at most N_e = 703 monomials at
    N_max = 2, only those that occur kept), 9 views of 32 x 32."""
    folder = sb.build(tmp_path / "street2", buildings=2, image=32)
    results = run_street_cli(tmp_path, folder, "render.max_bounces=2")
    assert len(results["parameters"]) == 36 and len(results["settings"]["views"]) == 9
    assert 37 <= results["n_monomials"] < 703
    assert all(0.0 <= x <= 1.0 for p in results["parameters"] for x in p["estimate"])
