"""The geometry bench's tessellated street and its table (no rendering: the section itself runs
in ``python -m bench --sections geometry``)."""
from __future__ import annotations

import numpy as np
import pytest

from bench.geometry import tessellated
from bench.geometry import markdown as section_geometry
from scenes import city_block


def _area(v, f) -> float:
    return float(0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum())


@pytest.mark.parametrize("n", [2_000, 20_000])
def test_tessellation_keeps_the_street(n):
    """About n triangles (cells are rounded per quad: within 25 %), every segment's area kept
    (float64 sums of exact grid cells: 1e-9 relative)."""
    segments = tessellated(n)
    assert list(segments) == list(city_block.hand_polygons())
    assert 0.75 * n < sum(len(f) for _, f in segments.values()) < 1.25 * n
    for name, quads in city_block.hand_polygons().items():
        want = sum(float(np.linalg.norm(np.cross(q[1] - q[0], q[3] - q[0]))) for q in quads)
        assert _area(*segments[name]) == pytest.approx(want, rel=1e-9)


def test_table_verdicts():
    rows = [{"triangles": 20_000, "obj_mib": 0.7, "convert_obj_s": 1.0, "convert_ply_s": 1.0, "load_s": 0.1,
             "pass_s": 1.0, "render_s": 0.5},
            {"triangles": 2_000_000, "obj_mib": 74.0, "convert_obj_s": 12.0, "convert_ply_s": 7.0, "load_s": 1.0,
             "pass_s": 1.6, "render_s": 1.0}]
    text = "\n".join(section_geometry({"rows": rows, "view": "view_000.png", "size": "192x144", "spp": 16, "reps": 5}))
    lines = [line for line in text.splitlines() if line.startswith("| 2")]
    assert lines[0].endswith("| 1.00 | 0.500 | 1.00 | **met** |")
    assert lines[1].endswith("| 1.60 | 1.000 | 2.00 | **not met** |")      # 1.6 x the pass > 1.5
