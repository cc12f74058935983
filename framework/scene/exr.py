"""Checked reading of a user's EXR inputs (observed images, environment maps)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from framework.errors import SceneError
from framework.images import read_exr


def read_exr_checked(path: Path, *, channels: tuple[str, ...], size: tuple[int, int] | None = None
                     ) -> np.ndarray:
    """Read an input EXR and check its channels, size and values (finite, non-negative).

    Raises :class:`SceneError` naming the file and the fix.
    """
    if not Path(path).is_file():
        raise SceneError(f"{path}: missing EXR file; add it or fix its name in the scene")
    try:
        img = read_exr(path)
    except Exception:
        raise SceneError(f"{path}: not a readable EXR file; re-export it as OpenEXR") from None
    if img.shape[-1] != len(channels):
        raise SceneError(f"{path}: {img.shape[-1]} channel(s); this scene needs {','.join(channels)}")
    if size is not None and img.shape[:2] != tuple(size):
        raise SceneError(f"{path}: image is {img.shape[1]}x{img.shape[0]}, its camera is "
                         f"{size[1]}x{size[0]}; resample it to the camera's size")
    bad = ~np.isfinite(img) | (img < 0)
    if bad.any():
        y, x, _ = np.argwhere(bad)[0]
        raise SceneError(f"{path}: {int(bad.sum())} NaN/Inf/negative values (first at x={x}, y={y}); "
                         "radiance must be finite and >= 0")
    return img
