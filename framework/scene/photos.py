"""Field photographs: the observed images of a scene folder as cameras and COLMAP deliver them,
decoded to linear radiance on the scene's pinhole cameras (``docs/scene-format.md``, section
"Field photographs").

For the COLMAP image ``name`` the loader reads ``images/<name>`` as delivered (``.exr``: linear
radiance; ``.png``: 8 or 16 bit; ``.jpg``/``.jpeg``), else ``images/<stem>.exr`` (the original
rule), and the optional mask ``masks/<name>.png`` (COLMAP's naming; 0 = ignore the pixel) or
``masks/<stem>.png`` (the name with its extension replaced by ``.png``: ``masks/corner_001.png``
for ``corner_001.png``); both at once is an error. Files in ``images/`` and ``masks/`` that no
view reads are listed in a warning (a misspelt mask would otherwise be ignored without a word).

Decoding: Pillow reads PNG and JPEG, except 16-bit colour PNGs, which Pillow reduces to 8 bits:
those are read with Mitsuba's ``Bitmap`` (libpng), which keeps the 16 bits. Codes become
encoded values ``code / (2^bits - 1)`` in float64, then linear values through the sRGB curve
(``encoding: srgb``, the default for PNG and JPEG) or as they are (``linear``, the default for
EXR). An alpha channel is dropped (it does not mask: give ``masks/<name>.png`` for that).

A pixel is unusable when masked, saturated (an encoded value >= ``saturation`` in any channel;
0.99 by default for 8/16-bit files, no limit for EXR unless given), black-clipped (a code 0 in
any channel, 8/16-bit files only) or, after undistortion, when the point it samples lies outside
the delivered image or interpolates an unusable pixel. Unusable pixels get weight 0 and value 0,
and the reason, the first that applies of outside, mask, saturated (black-clipped counts as
saturated: both are the encoding's ends), in :attr:`Photos.excluded`
(:data:`~framework.scene.model.EXCLUSION_REASONS`).

The quantisation of an 8/16-bit file is a uniform error of one code step: its standard deviation
in linear units is ``|d linear / d code| * step / sqrt(12)`` with ``step = 1 / (2^bits - 1)``,
carried through the resampling as sqrt(sum_i w_i^2 std_i^2). JPEG's compression error is larger
and is not modelled.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import numpy as np

from framework.errors import SceneError
from framework.images import srgb_decode
from framework.scene.exr import read_exr_checked
from framework.scene.model import EXCLUSION_REASONS, Camera, Photometry
from framework.scene.values import one_line
from framework.scene.undistort import Resampling, resampling_key

log = logging.getLogger(__name__)

#: the image formats read, by file extension (lower case)
SUFFIXES = {".exr": "OpenEXR", ".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG"}
#: encoded value at and above which an 8/16-bit pixel counts as saturated, unless scene.yaml says
DEFAULT_SATURATION = 0.99
SRGB_KNEE = 0.04045


@dataclass(frozen=True)
class Photos:
    """The observed images of every view, on the scene's pinhole cameras."""

    images: dict[str, np.ndarray]              # view -> (H, W, C) float32 linear, 0 where unusable
    weights: dict[str, np.ndarray] | None      # view -> (H, W) float32 in {0, 1}; None: all usable
    noise: dict[str, np.ndarray] | None        # view -> (H, W, C) float32; None: no 8/16-bit file
    files: tuple[Path, ...]                    # every image and mask read
    #: view -> (H, W) uint8: why a pixel is unusable, a code of EXCLUSION_REASONS (0: usable);
    #: None when every pixel is usable
    excluded: dict[str, np.ndarray] | None = None


@dataclass(frozen=True)
class _Decoded:
    """One delivered image, on its delivered camera."""

    linear: np.ndarray            # (H, W, C) float64
    usable: np.ndarray            # (H, W) bool
    std: np.ndarray | None        # (H, W, C) float64 quantisation std; None for EXR


def image_file(root: Path, camera_name: str) -> Path:
    """The observed image of a COLMAP image: ``images/<name>`` as delivered when that file exists
    with a format the loader reads, else the EXR of section 1 of the format, the name with its
    extension replaced by ``.exr`` (``street_003.png`` -> ``images/street_003.exr``,
    ``left/top_000.png`` -> ``images/left/top_000.exr``)."""
    delivered = root / "images" / PurePosixPath(camera_name)
    if delivered.suffix.lower() in SUFFIXES and delivered.is_file():
        return delivered
    return root / "images" / PurePosixPath(camera_name).with_suffix(".exr")


def mask_file(root: Path, camera_name: str) -> Path | None:
    """The mask of a COLMAP image, or None: COLMAP's naming ``masks/<name>.png``
    (``masks/corner_001.png.png``), or the plain one, the image's name with its extension
    replaced by ``.png`` (``masks/corner_001.png``; ``masks/left/top_000.png``).

    Raises
    ------
    SceneError
        When both files exist: which one was meant cannot be told.
    """
    colmap = root / "masks" / f"{camera_name}.png"
    plain = root / "masks" / PurePosixPath(camera_name).with_suffix(".png")
    found = [p for p in dict.fromkeys((colmap, plain)) if p.is_file()]
    if len(found) == 2:
        raise SceneError(f"{colmap} and {plain}: two masks for image {camera_name} (COLMAP's name "
                         "<image>.png and the plain one); keep one, delete the other")
    return found[0] if found else None


def _warn_unused(root: Path, files: list[Path]) -> None:
    """Log a warning naming every file in ``images/`` and ``masks/`` no view reads (hidden files
    aside): a mask or image under a name the loader does not look for is otherwise ignored."""
    read = {p.resolve() for p in files}
    for folder in ("images", "masks"):
        if not (root / folder).is_dir():
            continue
        unused = sorted(p.relative_to(root).as_posix() for p in (root / folder).rglob("*")
                        if p.is_file() and not p.name.startswith(".") and p.resolve() not in read)
        if unused:
            shown = ", ".join(unused[:8]) + (f", ... ({len(unused)} files)" if len(unused) > 8 else "")
            what = ("masks/<image name>.png or masks/<image stem>.png" if folder == "masks"
                    else "images/<image name> or images/<image stem>.exr")
            log.warning("%s: %s not read by any view of the COLMAP model (a view reads %s); "
                        "rename or remove %s", root, shown, what, "it" if len(unused) == 1 else "them")


def read_photos(root: Path, cameras: tuple[Camera, ...], channels: tuple[str, ...],
                photometry: Photometry) -> Photos | None:
    """Read, decode, mask and undistort the observed image of every camera.

    Parameters
    ----------
    root : Path
        The scene folder.
    cameras : tuple of Camera
        Every view of the COLMAP model; ``Camera.distortion`` says which ones to resample.
    channels : tuple of str
        The scene's channels.
    photometry : Photometry
        scene.yaml's ``photometry``.

    Returns
    -------
    Photos or None
        None when the folder has no ``images/``.

    Raises
    ------
    SceneError
        One line naming the file and the fix.
    """
    if not (root / "images").is_dir():
        return None
    _check_distinct(root, cameras)
    images, weights, noise, files, excluded = {}, {}, {}, [], {}
    resamplings: dict[tuple, Resampling] = {}
    for c in cameras:
        path = _existing_image(root, c.name)
        decoded = _decode(path, channels=channels, photometry=photometry, size=(c.height, c.width))
        files.append(path)
        usable = decoded.usable
        unmasked = np.ones_like(usable)
        mask = mask_file(root, c.name)
        if mask is not None:
            unmasked = _read_mask(mask, image=path, shape=usable.shape)
            usable = usable & unmasked
            files.append(mask)
        std = decoded.std
        if c.distortion is None:
            image, ok = np.where(usable[..., None], decoded.linear, 0.0), usable
            reason = _reason(np.ones_like(ok), unmasked, decoded.usable)
        else:
            key = resampling_key(c, photometry.resampling)
            if key not in resamplings:
                resamplings[key] = Resampling(source=c.delivered(), target=c.pinhole(),
                                              kernel=photometry.resampling)
            r = resamplings[key]
            image, ok = r.apply(decoded.linear, valid=usable)
            std = None if std is None else r.apply_std(std)
            reason = _reason(r.ok(), r.ok(unmasked), r.ok(decoded.usable))
        images[c.name] = image.astype(np.float32)
        weights[c.name] = ok.astype(np.float32)
        excluded[c.name] = np.where(ok, 0, reason).astype(np.uint8)
        if std is not None:
            noise[c.name] = np.where(ok[..., None], std, 0.0).astype(np.float32)
    _warn_unused(root, files)
    if noise:
        noise = {c.name: noise.get(c.name, np.zeros_like(images[c.name])) for c in cameras}
    all_usable = all(w.all() for w in weights.values())
    return Photos(images, None if all_usable else weights, noise or None, tuple(files),
                  None if all_usable else excluded)


def _reason(inside: np.ndarray, unmasked: np.ndarray, decodable: np.ndarray) -> np.ndarray:
    """``(H, W)`` code of :data:`EXCLUSION_REASONS` of the first that applies: outside the delivered
    image, masked, saturated or black-clipped (0 where none does)."""
    code = {r: i for i, r in enumerate(EXCLUSION_REASONS)}
    return np.select([~inside, ~unmasked, ~decodable], [code["outside"], code["mask"], code["saturated"]], 0)


def _check_distinct(root: Path, cameras) -> None:
    owner: dict[Path, str] = {}
    for c in cameras:
        path = image_file(root, c.name)
        if path in owner:
            raise SceneError(f"{path}: the images {owner[path]} and {c.name} would both read it; rename "
                             "one in the COLMAP model so their names differ beyond the extension")
        owner[path] = c.name


def _existing_image(root: Path, name: str) -> Path:
    """The image file of view ``name``; one line naming what to add where there is none."""
    path = image_file(root, name)
    if path.is_file():
        return path
    delivered = root / "images" / PurePosixPath(name)
    if delivered.is_file():
        raise SceneError(f"{delivered}: {delivered.suffix or 'extension-less'} images are not read; deliver "
                         f"the image as .exr, .png or .jpg, or add {path.relative_to(root).as_posix()}")
    raise SceneError(f"{path}: missing EXR file; add it or the image as delivered "
                     f"(images/{name}: .exr, .png or .jpg), or fix its name in the scene")


# ----------------------------------------------------------------------------------------------
# Decoding
# ----------------------------------------------------------------------------------------------

def _decode(path: Path, *, channels: tuple[str, ...], photometry: Photometry,
            size: tuple[int, int]) -> _Decoded:
    if path.suffix.lower() == ".exr":
        return _decode_exr(path, channels=channels, photometry=photometry, size=size)
    codes, top = _read_codes(path, what="image")
    if codes.shape[2] != len(channels):
        raise SceneError(_channel_problem(path, codes.shape[2], channels))
    _check_size(path, codes.shape[:2], size, "its camera")
    encoded = codes / float(top)
    saturation = DEFAULT_SATURATION if photometry.saturation is None else photometry.saturation
    usable = ~((encoded >= saturation).any(axis=2) | (codes == 0).any(axis=2))
    step_std = 1.0 / (top * np.sqrt(12.0))
    if (photometry.encoding or "srgb") == "srgb":
        return _Decoded(srgb_decode(encoded), usable, _srgb_slope(encoded) * step_std)
    return _Decoded(encoded, usable, np.full(encoded.shape, step_std))


def _decode_exr(path: Path, *, channels, photometry: Photometry, size) -> _Decoded:
    values = read_exr_checked(path, channels=channels, size=size).astype(np.float64)
    usable = np.ones(values.shape[:2], bool)
    if photometry.saturation is not None:
        usable = ~(values >= photometry.saturation).any(axis=2)
    linear = srgb_decode(values) if photometry.encoding == "srgb" else values
    return _Decoded(linear, usable, None)


def _srgb_slope(encoded: np.ndarray) -> np.ndarray:
    """d srgb_decode / d encoded (IEC 61966-2-1), float64."""
    return np.where(encoded <= SRGB_KNEE, 1.0 / 12.92,
                    2.4 / 1.055 * np.power((np.maximum(encoded, SRGB_KNEE) + 0.055) / 1.055, 1.4))


def _read_codes(path: Path, *, what: str) -> tuple[np.ndarray, int]:
    """The ``(H, W, C)`` integer codes of a PNG or JPEG file (alpha dropped) and the largest code
    of its bit depth (255 or 65535)."""
    from PIL import Image

    def undecodable(why: str) -> SceneError:
        for quoted in (f"'{path}'", f'"{path}"', str(path)):          # the line names it once
            why = why.replace(quoted, "")
        why = why.strip(" :") or "unreadable"
        fix = "re-export it as PNG or JPEG" if what == "image" else "re-export it as a grey PNG"
        return SceneError(f"{path}: {what} cannot be decoded ({why}); {fix}")

    with open(path, "rb") as fh:
        header = fh.read(26)
    if header[:8] == b"\x89PNG\r\n\x1a\n" and len(header) == 26 and header[24] == 16 and header[25] in (2, 4, 6):
        codes, top = _read_png16_colour(path, undecodable), 65535
    else:
        try:
            with Image.open(path) as im:
                im.load()
                fmt = im.format
                codes, top = _pillow_codes(im, header)
        except SceneError:
            raise
        except Exception as exc:  # Pillow: UnidentifiedImageError, OSError (truncated), SyntaxError...
            raise undecodable(one_line(exc) or type(exc).__name__) from None
        if fmt not in ("PNG", "JPEG"):
            raise undecodable(f"a {fmt} file, not PNG or JPEG")
    codes = codes[..., None] if codes.ndim == 2 else codes
    if codes.shape[2] in (2, 4):                     # grey + alpha, RGB + alpha
        codes = codes[..., :-1]
    return codes, top


def _pillow_codes(im, header: bytes) -> tuple[np.ndarray, int]:
    """Codes of an image Pillow has loaded."""
    mode = im.mode
    if mode.startswith("I;16"):
        return np.asarray(im).astype(np.uint16), 65535
    if mode == "I" and header[:8] == b"\x89PNG\r\n\x1a\n" and header[24] == 16:
        return np.asarray(im).astype(np.uint16), 65535
    if mode == "1":
        im = im.convert("L")
    elif mode in ("P", "PA"):
        im = im.convert("RGBA" if mode == "PA" or "transparency" in im.info else "RGB")
    elif mode in ("CMYK", "YCbCr", "LAB"):
        im = im.convert("RGB")
    if im.mode not in ("L", "LA", "RGB", "RGBA"):
        raise ValueError(f"pixel mode {mode}, not 8/16-bit grey or colour")
    return np.asarray(im).astype(np.uint8), 255


def _read_png16_colour(path: Path, undecodable) -> np.ndarray:
    """A 16-bit colour PNG through Mitsuba's Bitmap (libpng): Pillow would keep 8 of its bits."""
    import mitsuba as mi
    try:
        bitmap = mi.Bitmap(str(path))
    except Exception as exc:
        raise undecodable(one_line(exc) or type(exc).__name__) from None
    codes = np.array(bitmap, copy=True)
    if codes.dtype != np.uint16:
        raise undecodable(f"Mitsuba read it as {codes.dtype}, not 16 bit")
    return codes


def _channel_problem(path: Path, n: int, channels: tuple[str, ...]) -> str:
    if len(channels) == 1:
        return (f"{path}: a colour image ({n} channels); this scene is mono (one channel "
                f"{channels[0]}): deliver grey images")
    return (f"{path}: a grey image (1 channel); this scene needs {','.join(channels)}: deliver colour "
            "images, or set channels: mono in scene.yaml")


def _check_size(path: Path, shape: tuple[int, int], size: tuple[int, int], of: str) -> None:
    if tuple(shape) != tuple(size):
        raise SceneError(f"{path}: image is {shape[1]}x{shape[0]}, {of} is {size[1]}x{size[0]}; "
                         "give it that size")


def _read_mask(path: Path, *, image: Path, shape: tuple[int, int]) -> np.ndarray:
    """``(H, W)`` bool: True where the mask's code is not 0 (in any colour channel)."""
    codes, _ = _read_codes(path, what="mask")
    if codes.shape[:2] != tuple(shape):
        raise SceneError(f"{path}: mask is {codes.shape[1]}x{codes.shape[0]}, its image {image.name} is "
                         f"{shape[1]}x{shape[0]}; make the mask the image's size")
    return (codes != 0).any(axis=2)
