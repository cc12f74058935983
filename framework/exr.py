"""EXR input/output (OpenEXR), always float32 and contiguous (OpenEXR silently writes garbage otherwise)."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from framework.errors import SceneError


def read_exr(path: str | os.PathLike) -> tuple[np.ndarray, tuple[str, ...]]:
    """Read an EXR file as ((H, W, C) float32, channel names); RGB(A) order first, then sorted."""
    import OpenEXR
    with OpenEXR.File(str(path), separate_channels=True) as f:
        chans = f.channels()
        order = [c for c in ("R", "G", "B", "A") if c in chans] or sorted(chans)
        order += [c for c in sorted(chans) if c not in order]
        data = np.stack([np.asarray(chans[c].pixels, dtype=np.float32) for c in order], axis=-1)
    return data, tuple(order)


def write_exr(path: str | os.PathLike, image: np.ndarray, channels: tuple[str, ...]) -> None:
    """Write (H, W, C) (or (H, W) for one channel) as float32 EXR with the given channel names."""
    import OpenEXR
    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 2:
        img = img[..., None]
    if img.shape[-1] != len(channels):
        raise ValueError(f"image has {img.shape[-1]} channels, names given: {channels}")
    data = {c: np.ascontiguousarray(img[..., i], dtype=np.float32) for i, c in enumerate(channels)}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with OpenEXR.File(header, data) as f:
        f.write(str(path))


def read_exr_checked(path: Path, *, channels: tuple[str, ...], size: tuple[int, int] | None = None
                     ) -> np.ndarray:
    """Read an input EXR and check its channels, size and values (finite, non-negative).

    Raises :class:`SceneError` naming the file and the fix.
    """
    if not Path(path).is_file():
        raise SceneError(f"{path}: missing EXR file; add it or fix its name in the scene")
    try:
        img, names = read_exr(path)
    except Exception:
        raise SceneError(f"{path}: not a readable EXR file; re-export it as OpenEXR") from None
    if not set(channels) <= set(names):
        raise SceneError(f"{path}: channels {','.join(names)}; this scene needs {','.join(channels)}")
    img = np.ascontiguousarray(img[..., [names.index(c) for c in channels]])
    if size is not None and img.shape[:2] != tuple(size):
        raise SceneError(f"{path}: image is {img.shape[1]}x{img.shape[0]}, its camera is "
                         f"{size[1]}x{size[0]}; resample it to the camera's size")
    bad = ~np.isfinite(img) | (img < 0)
    if bad.any():
        y, x, _ = np.argwhere(bad)[0]
        raise SceneError(f"{path}: {int(bad.sum())} NaN/Inf/negative values (first at x={x}, y={y}); "
                         "radiance must be finite and >= 0")
    return img
