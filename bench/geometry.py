"""Section "geometry": converting, loading and one polynomial pass against the triangle count.

The mesh is ``city_block``'s street (:mod:`scenes.city_block`) as a photogrammetric mesh would
deliver it: every hand-built quad subdivided into a grid of equal cells (two triangles each)
so that the street has about N triangles (20k, 200k, 2M), written in survey coordinates as an
OBJ (``usemtl`` per segment, the slowest reader: text) and as a binary labelled PLY (double
coordinates, ``label`` per face, ``street.labels.yaml``). Each is converted with
:func:`framework.convert.convert` (the blind-view check included) against the street's COLMAP
model and photographs (rendered at :data:`VIEW` pixels from the hand-built folder). Then the
converted OBJ folder is loaded (:func:`framework.scene.load_scene`, Open3D's PLY reader) and the
symbolic method's polynomial pass of its first view is timed as section 1 times it (the least of
``reps`` after a warm-up; the least, :func:`fastest`), and beside it a plain Mitsuba ``path`` render of the same view at the
same spp (section 1's reference): what ray tracing alone costs on the larger mesh. The target (issue 29): 2M triangles convert in under a minute, and
their pass costs at most 1.5x the pass on 20k triangles.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import yaml

from bench.render_ratio import _pass_fn, _render_fn, build_problem
from bench.tables import f, table, yes
from framework.config import compose
from framework.convert import convert
from framework.scene import load_scene
from scenes import city_block

VIEW = (192, 144)
PHOTO_SPP = 64
TARGET_CONVERT_S = 60.0
TARGET_PASS_RATIO = 1.5


def tessellated(triangles: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The street's segments as grids of about ``triangles`` triangles in all (local metres).

    Every quad of :func:`scenes.city_block.hand_polygons` becomes an n x m grid of cells of side
    about s, with 2 (total area) / s^2 = ``triangles``.
    """
    polys = city_block.hand_polygons()
    area = sum(float(np.linalg.norm(np.cross(q[1] - q[0], q[3] - q[0]))) for qs in polys.values() for q in qs)
    side = math.sqrt(2 * area / triangles)
    out = {}
    for name, quads in polys.items():
        verts, faces, n0 = [], [], 0
        for q in quads:
            u, w = q[1] - q[0], q[3] - q[0]
            n, m = max(1, round(np.linalg.norm(u) / side)), max(1, round(np.linalg.norm(w) / side))
            s, t = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, m + 1), indexing="ij")
            verts.append(q[0] + s.reshape(-1, 1) * u + t.reshape(-1, 1) * w)
            i, j = np.meshgrid(np.arange(n), np.arange(m), indexing="ij")
            a = (i * (m + 1) + j).ravel()
            b, c, d = a + (m + 1), a + (m + 2), a + 1
            faces.append(np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]) + n0)
            n0 += (n + 1) * (m + 1)
        out[name] = (np.concatenate(verts), np.concatenate(faces))
    return out


def write_obj(path: Path, segments: dict, origin) -> Path:
    """An OBJ in survey coordinates (``origin`` added, 3 decimals), ``usemtl`` per segment."""
    with open(path, "w", encoding="utf-8") as f:
        n = 0
        for name, (v, faces) in segments.items():
            f.write(f"usemtl {name}\n")
            f.write("".join(f"v {x:.3f} {y:.3f} {z:.3f}\n" for x, y, z in (v + origin).tolist()))
            f.write("".join(f"f {a} {b} {c}\n" for a, b, c in (faces + n + 1).tolist()))
            n += len(v)
    return path


def write_ply(path: Path, segments: dict, origin) -> Path:
    """A binary PLY (double x, y, z; faces with an int ``label``) and its ``<stem>.labels.yaml``."""
    v = np.concatenate([s[0] for s in segments.values()]) + origin
    offsets = np.cumsum([0] + [len(s[0]) for s in segments.values()])[:-1]
    faces = np.concatenate([s[1] + o for s, o in zip(segments.values(), offsets)])
    labels = np.concatenate([np.full(len(s[1]), i) for i, s in enumerate(segments.values())])
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(v)}\nproperty double x\n"
            f"property double y\nproperty double z\nelement face {len(faces)}\n"
            "property list uchar int vertex_indices\nproperty int label\nend_header\n")
    rec = np.zeros(len(faces), dtype=[("n", "u1"), ("f", "<i4", 3), ("label", "<i4")])
    rec["n"], rec["f"], rec["label"] = 3, faces, labels
    with open(path, "wb") as f:
        f.write(head.encode())
        f.write(v.astype("<f8").tobytes())
        f.write(rec.tobytes())
    path.with_name(path.stem + ".labels.yaml").write_text(yaml.safe_dump(dict(enumerate(segments))))
    return path


def fastest(fn, reps: int) -> float:
    """The least of ``reps`` timed calls of ``fn`` after one warm-up call, in seconds: on a shared
    machine the least disturbed run (the median follows the other jobs' load)."""
    fn()
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def run(sizes, root: Path, log=print) -> dict:
    """Convert, load and pass at each of ``sizes.geometry_triangles``; returns ``{"rows": [...], ...}``."""
    root = Path(root)
    hand = city_block.build(root / "hand", width=VIEW[0], height=VIEW[1], spp=PHOTO_SPP)
    survey = hand / "survey"
    rows = []
    for n in sizes.geometry_triangles:
        segments = tessellated(n)
        tris = int(sum(len(f) for _, f in segments.values()))
        row = {"target": n, "triangles": tris}
        for kind, writer in (("obj", write_obj), ("ply", write_ply)):
            src = writer(root / f"street_{n}.{kind}", segments, np.asarray(city_block.ORIGIN))
            row[f"{kind}_mib"] = src.stat().st_size / 2**20
            t = time.perf_counter()
            convert(src, root / f"{kind}_{n}", sparse=survey / "sparse", emitters=survey / "emitters.yaml",
                    images=hand / "images", kernels={"*/Window": ("diffuse", "specular")})
            row[f"convert_{kind}_s"] = time.perf_counter() - t
        folder = root / f"obj_{n}"
        row["load_s"] = fastest(lambda: load_scene(folder), sizes.geometry_reps)
        problem, method = build_problem(compose(["method=symbolic", "scene=city_block", f"scene.dir={folder}", "cache.dir=null",
                                                 *sizes.extra]))
        pass_fn, x0 = _pass_fn(problem, method, sizes.geometry_spp)
        row["pass_s"] = fastest(pass_fn, sizes.geometry_reps)
        row["render_s"] = fastest(_render_fn(problem, sizes.geometry_spp, x0), sizes.geometry_reps)
        rows.append(row)
        log(f"[geometry] {tris} triangles: convert OBJ {row['convert_obj_s']:.1f} s, PLY {row['convert_ply_s']:.1f} s, "
            f"load {row['load_s']:.2f} s, pass {row['pass_s']:.2f} s, path render {row['render_s']:.2f} s")
    cam = problem.cameras[0]
    return {"rows": rows, "view": cam.name, "size": f"{cam.width}x{cam.height}", "spp": sizes.geometry_spp,
            "reps": sizes.geometry_reps, "segments": len(problem.scene.segments)}


# ----------------------------------------------------------------------------------------------
# BENCHMARKS.md
# ----------------------------------------------------------------------------------------------

def markdown(r: dict) -> list[str]:
    """Section "geometry": convert, load and pass time against the triangle count (:mod:`bench.geometry`)."""
    rows = r["rows"]
    if not rows:
        return []
    base, base_render = rows[0]["pass_s"], rows[0].get("render_s")
    lines = ["## 9. Geometry as a survey delivers it", "",
             f"city_block's street tessellated into about N triangles (every quad a grid of equal cells), in survey "
             f"coordinates, converted by `python -m framework.convert` from an OBJ and from a binary labelled PLY "
             f"(the blind-view check included), the OBJ's folder loaded (`load_scene`), and the polynomial pass "
             f"(`method=symbolic`) of {r['view']} ({r['size']}, {r['spp']} spp) timed as section 1 "
             f"(the least of {r['reps']} runs after a warm-up: the machine is shared), and a plain Mitsuba `path` render of the view at the same spp (what ray tracing "
             f"alone costs as the mesh grows). Targets: convert 2M triangles in under {TARGET_CONVERT_S:g} s; "
             f"pass within {TARGET_PASS_RATIO:g}x the pass on the smallest mesh.", ""]
    body = [[x["triangles"], f(x["obj_mib"], 1), f(x["convert_obj_s"], 2), f(x["convert_ply_s"], 2), f(x["load_s"], 2),
             f(x["pass_s"], 3), f(x["pass_s"] / base, 2), f(x.get("render_s"), 3),
             f(x["render_s"] / base_render, 2) if base_render else "",
             yes(max(x["convert_obj_s"], x["convert_ply_s"]) < TARGET_CONVERT_S and x["pass_s"] / base <= TARGET_PASS_RATIO)]
            for x in rows]
    return lines + table(["triangles", "OBJ (MiB)", "convert OBJ (s)", "convert PLY (s)", "load (s)", "pass (s)",
                          "pass / smallest", "path render (s)", "render / smallest", "targets"], body) + [""]
