"""Comparison of generated scene files by content, not by bytes.

numpy dispatches its ufuncs (trigonometry above all) to SIMD code chosen by the CPU: the same
scene builder writes vertices one ulp (about 1e-16 relative) apart on an AVX2 and an AVX-512
machine, and prints a COLMAP pose with other last digits. A test that compares a file generated
here with one committed from another machine therefore parses both and compares

- numbers (PLY vertices, COLMAP text fields, YAML values, EXR pixels) within ``RTOL`` relative
  and ``ATOL`` absolute, 10⁶ ulp of float64 and far below anything a scene or an estimate can
  feel (a 40 m street at 1e-9 relative is 40 nm);
- everything else (PLY faces and header, text tokens, YAML keys and strings, image sizes)
  exactly.

Files of another kind (PNG, JPEG) are compared byte for byte.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml

RTOL = 1e-9
ATOL = 1e-12
EXR_RTOL = 1e-6         # float32 pixels: a few ulp of float32


def differences(a: Path, b: Path) -> list[str]:
    """What differs between two folders of scene files, one line per file (empty: the same).

    Parameters
    ----------
    a, b : Path
        Two folders; every file below each is compared with its namesake in the other.
    """
    files_a = {p.relative_to(a) for p in a.rglob("*") if p.is_file()}
    files_b = {p.relative_to(b) for p in b.rglob("*") if p.is_file()}
    out = [f"{f}: only in {a}" for f in sorted(files_a - files_b)]
    out += [f"{f}: only in {b}" for f in sorted(files_b - files_a)]
    for f in sorted(files_a & files_b):
        why = file_difference(a / f, b / f)
        if why:
            out.append(f"{f}: {why}")
    return out


def file_difference(a: Path, b: Path) -> str | None:
    """Why two files differ in content (None where they agree), by the kind their suffix names."""
    if a.read_bytes() == b.read_bytes():
        return None
    compare = {".ply": _ply, ".txt": _text, ".yaml": _yaml, ".exr": _exr}.get(a.suffix.lower())
    return compare(a, b) if compare else "bytes differ"


def _close(x, y, rtol: float = RTOL) -> bool:
    return bool(np.allclose(np.asarray(x, float), np.asarray(y, float), rtol=rtol, atol=ATOL))


def _ply(a: Path, b: Path) -> str | None:
    import open3d as o3d

    ma, mb = (o3d.io.read_triangle_mesh(str(p)) for p in (a, b))
    va, vb = np.asarray(ma.vertices), np.asarray(mb.vertices)
    fa, fb = np.asarray(ma.triangles), np.asarray(mb.triangles)
    if va.shape != vb.shape or not np.array_equal(fa, fb):
        return f"PLY structure differs: vertices {va.shape} / {vb.shape}, faces {fa.shape} / {fb.shape}"
    if not _close(va, vb):
        return f"vertices differ by up to {np.abs(va - vb).max():.3g}"
    return None


def _number(token: str) -> float | None:
    try:
        value = float(token)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def _text(a: Path, b: Path) -> str | None:
    lines_a, lines_b = a.read_text().splitlines(), b.read_text().splitlines()
    if len(lines_a) != len(lines_b):
        return f"{len(lines_a)} / {len(lines_b)} lines"
    for i, (la, lb) in enumerate(zip(lines_a, lines_b), 1):
        ta, tb = la.split(), lb.split()
        if len(ta) != len(tb):
            return f"line {i}: {len(ta)} / {len(tb)} fields"
        for x, y in zip(ta, tb):
            nx, ny = _number(x), _number(y)
            same = x == y if nx is None or ny is None else _close(nx, ny)
            if not same:
                return f"line {i}: {x!r} / {y!r}"
    return None


def _same_tree(x, y) -> bool:
    if isinstance(x, dict) and isinstance(y, dict):
        return x.keys() == y.keys() and all(_same_tree(x[k], y[k]) for k in x)
    if isinstance(x, list) and isinstance(y, list):
        return len(x) == len(y) and all(_same_tree(u, v) for u, v in zip(x, y))
    numbers = (int, float)
    if isinstance(x, numbers) and isinstance(y, numbers) and not isinstance(x, bool) and not isinstance(y, bool):
        return _close(x, y)
    return x == y


def _yaml(a: Path, b: Path) -> str | None:
    ya, yb = (yaml.safe_load(p.read_text()) for p in (a, b))
    return None if _same_tree(ya, yb) else "YAML content differs"


def _exr(a: Path, b: Path) -> str | None:
    from framework.images import read_exr

    ia, ib = read_exr(a), read_exr(b)
    if ia.shape != ib.shape:
        return f"EXR shapes {ia.shape} / {ib.shape}"
    if not _close(ia, ib, EXR_RTOL):
        return f"EXR pixels differ by up to {np.abs(ia - ib).max():.3g}"
    return None
