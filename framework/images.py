"""Image input/output, display and comparison helpers.

EXR files hold linear radiance with channels ``R, G, B`` (colour) or ``Y`` (mono).
Arrays are ``(H, W, C)`` float32 throughout; display images are ``uint8`` sRGB.
"""

from __future__ import annotations

import os

import numpy as np

_CHANNEL_ORDERS = (("R", "G", "B"), ("Y",))


def read_exr(path: str | os.PathLike) -> np.ndarray:
    """Read an EXR file as a float32 array.

    Parameters
    ----------
    path : str or path-like
        The EXR file.

    Returns
    -------
    numpy.ndarray
        ``(H, W, C)`` float32: channels ``R, G, B`` in that order, or ``Y``; a file
        with other channel names gives them in alphabetical order.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    """
    import OpenEXR

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"no EXR file at {path}")
    with OpenEXR.File(path, separate_channels=True) as exr:
        planes = {name: np.asarray(ch.pixels, dtype=np.float32)
                  for name, ch in exr.channels().items()}
    names = next((order for order in _CHANNEL_ORDERS if set(order) <= set(planes)),
                 tuple(sorted(planes)))
    return np.ascontiguousarray(np.stack([planes[n] for n in names], axis=-1))


def write_exr(path: str | os.PathLike, array: np.ndarray, channels=None) -> None:
    """Write an array as a float32 EXR file (ZIP compressed).

    Parameters
    ----------
    path : str or path-like
        Destination file; its folder must exist.
    array : numpy.ndarray
        ``(H, W)`` or ``(H, W, C)``; any layout or float dtype (it is made contiguous
        float32 before writing: OpenEXR writes non-contiguous arrays as garbage).
    channels : sequence of str, optional
        One name per channel; default ``("R", "G", "B")`` for 3 channels, ``("Y",)`` for 1.

    Raises
    ------
    ValueError
        If the array's shape and the channel names disagree.
    """
    import OpenEXR

    arr = np.asarray(array)
    if arr.ndim == 2:
        arr = arr[..., None]
    if arr.ndim != 3:
        raise ValueError(f"write_exr needs an (H, W) or (H, W, C) array, got shape {arr.shape}")
    if channels is None:
        channels = {3: ("R", "G", "B"), 1: ("Y",)}.get(arr.shape[2])
    if channels is None or len(channels) != arr.shape[2]:
        raise ValueError(f"write_exr: {arr.shape[2]} channels but names {channels!r}")
    planes = {name: np.ascontiguousarray(arr[..., i], dtype=np.float32)
              for i, name in enumerate(channels)}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, planes) as exr:
        exr.write(os.fspath(path))


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1) of linear values in [0, 1]."""
    linear = np.asarray(linear, dtype=np.float64)
    return np.where(linear <= 0.0031308, 12.92 * linear,
                    1.055 * np.power(np.maximum(linear, 0.0031308), 1.0 / 2.4) - 0.055)


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """The inverse of :func:`srgb_encode`: encoded values in [0, 1] to linear, float64."""
    encoded = np.asarray(encoded, dtype=np.float64)
    return np.where(encoded <= 0.04045, encoded / 12.92,
                    np.power((np.maximum(encoded, 0.04045) + 0.055) / 1.055, 2.4))


def auto_exposure(img: np.ndarray) -> float:
    """Exposure that maps the 99th percentile of ``img`` to 1 (1 for a black image)."""
    finite = np.asarray(img, dtype=np.float32)
    finite = finite[np.isfinite(finite)]
    p99 = float(np.percentile(finite, 99)) if finite.size else 0.0
    return 1.0 / p99 if p99 > 0 else 1.0


def tonemap(img: np.ndarray, *, exposure: float | None = None) -> np.ndarray:
    """Turn linear radiance into a displayable sRGB image.

    Parameters
    ----------
    img : numpy.ndarray
        ``(H, W)`` or ``(H, W, C)`` linear radiance; one channel is shown grey.
    exposure : float, optional
        Multiplier applied before encoding; default maps the 99th percentile to white.

    Returns
    -------
    numpy.ndarray
        ``(H, W, 3)`` uint8 (``(H, W)`` for a 2-D input).
    """
    arr = np.asarray(img, dtype=np.float32)
    if arr.ndim not in (2, 3):
        raise ValueError(f"tonemap needs an (H, W) or (H, W, C) array, got shape {arr.shape}")
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = np.repeat(arr, 3, axis=2)
    elif arr.ndim == 3 and arr.shape[2] != 3:
        arr = arr[..., :3]
    if exposure is None:
        exposure = auto_exposure(arr)
    scaled = np.nan_to_num(arr * np.float32(exposure), nan=0.0, posinf=1.0, neginf=0.0)
    encoded = srgb_encode(np.clip(scaled, 0.0, 1.0))
    return np.round(encoded * 255.0).astype(np.uint8)


def write_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write a ``uint8`` image ``(H, W)``, ``(H, W, 1)``, ``(H, W, 3)`` or ``(H, W, 4)`` as PNG."""
    arr = np.asarray(image)
    if arr.dtype != np.uint8:
        raise ValueError(f"write_png needs uint8 data, got {arr.dtype} (use tonemap first)")
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    arr = np.ascontiguousarray(arr)
    try:
        from PIL import Image
    except ImportError:  # pragma: no cover - PIL ships with matplotlib
        import matplotlib.image as mpimg
        mpimg.imsave(os.fspath(path), arr, cmap="gray" if arr.ndim == 2 else None)
        return
    Image.fromarray(arr).save(os.fspath(path), format="PNG", compress_level=1)


def segment_palette(n: int) -> np.ndarray:
    """``(n, 3)`` float colours in [0, 1], one per segment (tab20, then an HSV wheel)."""
    from matplotlib import colormaps

    if n <= 20:
        return np.asarray(colormaps["tab20"].colors, dtype=np.float64)[:n]
    return np.asarray(colormaps["hsv"](np.linspace(0, 1, n, endpoint=False))[:, :3])


NO_SEGMENT_RGB = (40, 40, 40)


def colorize_segments(seg_map: np.ndarray, n: int) -> np.ndarray:
    """Colour a segment index map.

    Parameters
    ----------
    seg_map : numpy.ndarray
        ``(H, W)`` integer map; ``-1`` means no segment (sky).
    n : int
        Number of segments (indices ``0 .. n-1``).

    Returns
    -------
    numpy.ndarray
        ``(H, W, 3)`` uint8; pixels without a segment are dark grey.
    """
    seg = np.asarray(seg_map)
    if seg.ndim != 2 or not np.issubdtype(seg.dtype, np.integer):
        raise ValueError(f"segment map must be a 2-D integer array, got {seg.dtype} {seg.shape}")
    if seg.size and (seg.min() < -1 or seg.max() >= n):
        raise ValueError(f"segment indices must lie in [-1, {n - 1}], got [{seg.min()}, {seg.max()}]")
    lut = np.vstack([np.round(segment_palette(n) * 255).reshape(-1, 3),
                     np.asarray([NO_SEGMENT_RGB], dtype=np.float64)]).astype(np.uint8)
    return lut[np.where(seg < 0, n, seg)]


def _ssim_window(shape) -> int | None:
    """Largest odd SSIM window <= 7 that fits the image, or None below 3 pixels."""
    side = min(shape[0], shape[1])
    win = min(7, side if side % 2 else side - 1)
    return win if win >= 3 else None


def image_metrics(observed: np.ndarray, reconstruction: np.ndarray) -> dict:
    """RMSE, PSNR and SSIM of a reconstruction against the observed image.

    Parameters
    ----------
    observed, reconstruction : numpy.ndarray
        Same shape, ``(H, W)`` or ``(H, W, C)``, linear radiance.

    Returns
    -------
    dict
        ``rmse``, ``psnr`` (dB, ``inf`` for identical images) and ``ssim`` (``nan`` for
        images under 3x3). The data range is ``observed.max() - observed.min()`` (1 for
        a constant observed image).
    """
    from skimage.metrics import peak_signal_noise_ratio, structural_similarity

    obs = np.asarray(observed, dtype=np.float64)
    rec = np.asarray(reconstruction, dtype=np.float64)
    if obs.shape != rec.shape:
        raise ValueError(f"image shapes differ: observed {obs.shape}, reconstruction {rec.shape}")
    if obs.ndim == 2:
        obs, rec = obs[..., None], rec[..., None]
    data_range = float(obs.max() - obs.min()) or 1.0
    rmse = float(np.sqrt(np.mean((obs - rec) ** 2)))
    psnr = float("inf") if rmse == 0 else float(
        peak_signal_noise_ratio(obs, rec, data_range=data_range))
    win = _ssim_window(obs.shape)
    ssim = float("nan") if win is None else float(structural_similarity(
        obs, rec, data_range=data_range, channel_axis=-1, win_size=win))
    return {"rmse": rmse, "psnr": psnr, "ssim": ssim}
