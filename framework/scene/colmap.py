"""The COLMAP model of a scene folder (``sparse/``, ``docs/scene-format.md``), read with pycolmap.

pycolmap reports a broken text model with bare C++ failures (``unordered_map::at``, ``Rig with
ID 7 does not exist``, ``Check failed: inserted``). :func:`read_model` therefore first parses the
text files minimally (field counts, ids, names, frames) to name the file, the line and the fix
itself, and reduces whatever pycolmap still raises to one line.

Where the poses come from: pycolmap 4.2.1 (COLMAP >= 3.12) reads ``rigs.txt`` and
``frames.txt`` when both exist and then takes each image's pose from its frame
(``sensor_from_rig · rig_from_world``): the pose written in ``images.txt`` is parsed and
dropped. Without those files every pose comes from ``images.txt``. The loader keeps pycolmap's
choice, records the file (:attr:`ColmapModel.pose_source`, then ``Scene.pose_source``) and
refuses a text model whose ``images.txt`` disagrees with its frames, since an edit of
``images.txt`` alone would otherwise be ignored without a word.

Cameras: ``SIMPLE_PINHOLE`` and ``PINHOLE`` with fx == fy are used as they are; ``PINHOLE``
with fx != fy and the distorted ``SIMPLE_RADIAL``, ``RADIAL`` and ``OPENCV`` become the pinhole
camera :func:`framework.scene.undistort.pinhole_for` (same size and principal point,
f = max(fx, fy)), the delivered camera kept in :attr:`Camera.distortion` for the loader to
resample the photographs (:mod:`framework.scene.photos`). Fisheye and other models are refused.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import numpy as np

from framework.errors import SceneError
from framework.scene.model import Camera
from framework.scene.values import one_line
from framework.scene.undistort import DISTORTED_MODELS, PINHOLE_MODELS, pinhole_for

log = logging.getLogger(__name__)

MODEL_PARAMS = {"SIMPLE_PINHOLE": ("f", "cx", "cy"), "PINHOLE": ("fx", "fy", "cx", "cy"),
                "SIMPLE_RADIAL": ("f", "cx", "cy", "k"), "RADIAL": ("f", "cx", "cy", "k1", "k2"),
                "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")}
ACCEPTED_MODELS = PINHOLE_MODELS + DISTORTED_MODELS
#: COLMAP models with a fisheye (non-perspective) projection
FISHEYE_MODELS = ("SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE", "OPENCV_FISHEYE", "THIN_PRISM_FISHEYE",
                  "RAD_TAN_THIN_PRISM_FISHEYE", "SIMPLE_FISHEYE", "FISHEYE", "FOV", "EUCM")
#: relative difference of fx and fy below which a PINHOLE camera has square pixels
SQUARE_TOLERANCE = 1e-6
CORE = ("cameras", "images", "points3D")
RIG = ("rigs", "frames")
# Relative agreement of an images.txt pose with its frame: text models hold 17 digits, so
# rounding stays far below it and any real edit far above.
POSE_TOLERANCE = 1e-6
IMAGE_LINE = "IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME"


@dataclass(frozen=True)
class ColmapModel:
    """The views of a scene folder and where they were read from."""

    cameras: tuple[Camera, ...]     # sorted by name
    files: dict[str, Path]          # what pycolmap read: cameras, images, points3D[, rigs, frames]
    pose_source: str                # the file the poses came from, relative to the scene folder


@dataclass(frozen=True)
class _ImageLine:
    """The first line of an image in ``images.txt``."""

    number: int                     # line number in the file
    image_id: int
    pose: np.ndarray                # QW QX QY QZ TX TY TZ
    camera_id: int
    name: str


def read_model(root: Path, *, sparse: Path | None = None) -> ColmapModel:
    """Read and check the COLMAP model ``root/sparse``.

    Parameters
    ----------
    root : Path
        The scene folder.
    sparse : Path, optional
        The model's folder, when it is not ``root/sparse`` (the converter reads a delivered one).

    Returns
    -------
    ColmapModel

    Raises
    ------
    SceneError
        One line naming the file (and line) and the fix.
    """
    sparse = root / "sparse" if sparse is None else Path(sparse)
    files = _model_files(sparse)
    lines = _check_text(files) if files["images"].suffix == ".txt" else None
    rec = _reconstruction(sparse)
    if lines is None:
        _check_names([image.name for image in rec.images.values()], files["images"])
    cameras = tuple(sorted((_camera(rec, image, files["cameras"]) for image in rec.images.values()),
                           key=lambda c: c.name))
    if not cameras:
        raise SceneError(f"{files['images']}: the COLMAP model has no images; register at least one")
    pose_file = files.get("frames", files["images"])
    if lines is not None and "frames" in files:
        _check_poses_agree(rec, lines, files)
    source = pose_file.relative_to(root).as_posix() if pose_file.is_relative_to(root) else pose_file.as_posix()
    log.info("%s: camera poses read from %s", root.name, source)
    return ColmapModel(cameras, files, source)


def _model_files(sparse: Path) -> dict[str, Path]:
    """The files pycolmap reads, by kind: binary when cameras, images and points3D ``.bin`` all
    exist, text otherwise; rigs and frames of the same format where present."""
    for ext in (".bin", ".txt"):
        files = {kind: sparse / f"{kind}{ext}" for kind in CORE + RIG}
        if all(files[kind].is_file() for kind in CORE):
            lone = [files[kind] for kind in RIG if files[kind].is_file()]
            if len(lone) == 1:
                other = next(files[kind].name for kind in RIG if files[kind] != lone[0])
                raise SceneError(f"{lone[0]}: present without {other}; pycolmap reads the two together: "
                                 f"add {other}, or delete {lone[0].name} to take every pose from images{ext}")
            return {kind: path for kind, path in files.items() if path.is_file()}
    found = sorted(p.name for p in sparse.glob("*.*") if p.stem in CORE + RIG) if sparse.is_dir() else []
    raise SceneError(f"{sparse}: missing COLMAP model (found: {', '.join(found) or 'nothing'}); add cameras, "
                     "images and points3D, all .txt or all .bin (an empty points3D.txt will do)")


def _reconstruction(sparse: Path):
    import pycolmap
    try:
        return pycolmap.Reconstruction(str(sparse))
    except Exception as exc:  # pycolmap raises RuntimeError/ValueError/IndexError with C++ text
        raise SceneError(f"{sparse}: unreadable COLMAP model ({one_line(exc)}); fix that file or "
                         "re-export the model with COLMAP") from None


def _camera(rec, image, cameras_file: Path) -> Camera:
    """The pinhole :class:`Camera` of ``image``, checked, with the delivered camera where it
    differs (:attr:`Camera.distortion`)."""
    c = rec.cameras[image.camera_id]
    model = c.model.name
    what = f"{cameras_file}: camera {image.camera_id} ({_images_of(rec, image.camera_id)})"
    if model not in ACCEPTED_MODELS:
        kind = "a fisheye model" if model in FISHEYE_MODELS else "a model the loader does not resample"
        raise SceneError(f"{what} is {model}, {kind}; undistort the images to a pinhole camera (colmap "
                         "image_undistorter) or use SIMPLE_RADIAL, RADIAL or OPENCV")
    if c.width <= 0 or c.height <= 0:
        raise SceneError(f"{what} is {c.width}x{c.height} pixels; give its WIDTH and HEIGHT (> 0)")
    fx, fy = c.focal_length_x, c.focal_length_y
    if not (np.isfinite([fx, fy]).all() and fx > 0 and fy > 0):
        raise SceneError(f"{what} has focal length {fx:g}, {fy:g}; focal lengths are > 0 pixels "
                         "(flip a mirrored image instead)")
    params = tuple(float(x) for x in c.params)
    if not np.isfinite(params).all():
        raise SceneError(f"{what} has NaN/Inf parameters ({' '.join(f'{x:g}' for x in params)}); fix them")
    T = np.asarray(image.cam_from_world().matrix(), dtype=float)
    if not np.isfinite(T).all():
        raise SceneError(f"{cameras_file.parent}: image {image.name} has a NaN/Inf pose; fix its pose")
    cx, cy = float(c.principal_point_x), float(c.principal_point_y)
    square = abs(fx - fy) <= SQUARE_TOLERANCE * fx
    coefficients = params[len(MODEL_PARAMS[model]) - len(_distortion_names(model)):]
    _check_distortion(c, model, coefficients, what)
    if square and not any(coefficients):
        return Camera(image.name, int(c.width), int(c.height), float(fx), cx, cy, T, camera_id=int(image.camera_id))
    f = float(pinhole_for(c).focal_length_x)
    return Camera(image.name, int(c.width), int(c.height), f, cx, cy, T, distortion=(model, params),
                  camera_id=int(image.camera_id))


def article(word: str) -> str:
    """``a`` or ``an`` before a model name read letter by letter or as a word (an OPENCV, a RADIAL)."""
    return "an" if word[:1].upper() in "AEIOU" else "a"


def _images_of(rec, camera_id: int, *, shown: int = 5) -> str:
    """``of image a.png`` or ``of images a.png, b.png, ... and N more (M images)``: every image
    that uses camera ``camera_id`` (a fix of the camera concerns them all)."""
    names = sorted(im.name for im in rec.images.values() if im.camera_id == camera_id)
    if len(names) == 1:
        return f"of image {names[0]}"
    more = f" and {len(names) - shown} more ({len(names)} images)" if len(names) > shown else ""
    return f"of images {', '.join(names[:shown])}{more}"


#: samples of the undistorted radius when checking that a radial distortion does not fold
FOLD_SAMPLES = 4096


def _check_distortion(c, model: str, coefficients: tuple[float, ...], what: str) -> None:
    """A radial distortion must not fold the image: r -> r (1 + k1 r^2 + k2 r^4) must increase
    over every radius the image covers (normalised, from the principal point to its farthest
    corner), or two directions land on one pixel and the resampling reads from the wrong places.
    A principal point outside the image is logged as a warning. The tangential terms of OPENCV
    (p1, p2) are left out of the fold check.

    Raises
    ------
    SceneError
        Naming the camera and every image that uses it (``what``).
    """
    if model not in ("SIMPLE_RADIAL", "RADIAL", "OPENCV"):
        return
    k1 = coefficients[0]
    k2 = coefficients[1] if model in ("RADIAL", "OPENCV") else 0.0
    fx, fy = float(c.focal_length_x), float(c.focal_length_y)
    cx, cy, w, h = float(c.principal_point_x), float(c.principal_point_y), float(c.width), float(c.height)
    if not (0 <= cx <= w and 0 <= cy <= h):
        log.warning("%s: principal point (%g, %g) lies outside the %gx%g image; check the calibration",
                    what, cx, cy, w, h)
    reach = max(np.hypot((x - cx) / fx, (y - cy) / fy) for x in (0.0, w) for y in (0.0, h))
    # the distorted radius d(r) = r (1 + k1 r^2 + k2 r^4) must rise until it reaches ``reach``
    r = np.linspace(0.0, 1.0, FOLD_SAMPLES)
    top = 1.0
    while True:
        rr = r * top
        d = rr * (1 + k1 * rr**2 + k2 * rr**4)
        slope = 1 + 3 * k1 * rr**2 + 5 * k2 * rr**4
        falls = np.flatnonzero(slope <= 0)
        end = falls[0] if falls.size else None
        if end is not None or d[-1] >= reach or top > 1e3:
            break
        top *= 4
    highest = d[:end].max() if end is not None else d.max()
    if end is not None and highest < reach:
        names = ", ".join(f"{n}={x:g}" for n, x in zip(("k1", "k2") if k2 else ("k",), (k1, k2)))
        raise SceneError(f"{what}: its {model} distortion ({names}) folds the image: the distorted radius "
                         f"stops growing at {highest:.3g} (normalised), short of the {reach:.3g} of the "
                         "image's farthest corner, so pixels there map to two directions; fix the "
                         "calibration (the sign or size of the coefficients)")


def _distortion_names(model: str) -> tuple[str, ...]:
    """The distortion coefficients among the parameters of an accepted model."""
    return tuple(n for n in MODEL_PARAMS[model] if n not in ("f", "fx", "fy", "cx", "cy"))


def _check_names(names: list[str], images_file: Path) -> None:
    """Image names are paths below ``images/`` (``left/top_000.png``), listed once each; an
    absolute name or one with ``..`` would read outside the scene folder."""
    seen = set()
    for name in names:
        parts = PurePosixPath(name.replace("\\", "/"))
        if parts.is_absolute() or ".." in parts.parts:
            raise SceneError(f"{images_file}: image name '{name}' leaves the scene folder (absolute or "
                             "'..'); name images by paths inside images/, e.g. left/top_000.png")
        if name in seen:
            raise SceneError(f"{images_file}: image '{name}' is listed twice; list each image once")
        seen.add(name)


# ----------------------------------------------------------------------------------------------
# The text model, checked before pycolmap reads it
# ----------------------------------------------------------------------------------------------

def _check_text(files: dict[str, Path]) -> dict[int, _ImageLine]:
    """Check what pycolmap reports badly or not at all; the images of ``images.txt`` by id."""
    camera_ids = _camera_ids(files["cameras"])
    images = _image_lines(files["images"])
    for image in images.values():
        if image.camera_id not in camera_ids:
            raise SceneError(f"{files['images']}: line {image.number}: image {image.name} uses camera "
                             f"{image.camera_id}, which {files['cameras'].name} does not define; add the "
                             "camera or fix the image's CAMERA_ID")
    _check_names([image.name for image in images.values()], files["images"])
    if "frames" in files:
        _check_frames(files, images)
    return images


def _data_lines(path: Path):
    """(line number, fields) of every line that is neither blank nor a ``#`` comment."""
    for n, line in enumerate(path.read_text(errors="replace").splitlines(), start=1):
        if line.strip() and not line.lstrip().startswith("#"):
            yield n, line.split()


def _camera_ids(path: Path) -> dict[int, int]:
    """Camera id -> line number of ``cameras.txt``."""
    ids: dict[int, int] = {}
    for n, f in _data_lines(path):
        if len(f) < 4 or not all(_reads_as(int, x) for x in (f[0], f[2], f[3])):
            raise SceneError(f"{path}: line {n} is not 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS...'; fix it")
        cid, expected = int(f[0]), _model_params(f[1])
        if expected is None:
            raise SceneError(f"{path}: line {n}: camera model '{f[1]}' is not a COLMAP model; use "
                             f"{', '.join(ACCEPTED_MODELS)}")
        if cid in ids:
            raise SceneError(f"{path}: line {n}: camera {cid} is already defined on line {ids[cid]}; "
                             "give each camera its own CAMERA_ID")
        if expected and len(f) - 4 != len(expected):
            raise SceneError(f"{path}: line {n}: {article(f[1])} {f[1]} camera has {len(expected)} parameters "
                             f"({' '.join(expected)}), this line {len(f) - 4}; fix the line")
        ids[cid] = n
    return ids


def _model_params(model: str) -> tuple[str, ...] | None:
    """The parameter names of a COLMAP camera model (pycolmap's list for models the loader refuses
    later, with the image that uses them), None for a name COLMAP does not know."""
    if model in MODEL_PARAMS:
        return MODEL_PARAMS[model]
    import pycolmap
    if model not in pycolmap.CameraModelId.__members__ or model == "INVALID":
        return None
    return tuple(pycolmap.Camera(model=model).params_info.split(", "))


def _image_lines(path: Path) -> dict[int, _ImageLine]:
    """The images of ``images.txt`` by id. Like COLMAP, the line after an image's line is its
    2D points (possibly empty); COLMAP drops an image without it, we refuse it."""
    lines = path.read_text(errors="replace").splitlines()
    images: dict[int, _ImageLine] = {}
    number = 0                                  # of the line read last, counted from 1
    while number < len(lines):
        text = lines[number].strip()
        number += 1
        if not text or text.startswith("#"):
            continue
        image = _image_line(text.split(), number, path)
        if number == len(lines):
            raise SceneError(f"{path}: line {number}: image {image.name} has no second line (its 2D "
                             "points, may be empty); add an empty line after it, or pycolmap drops the image")
        number += 1
        _check_points_line(lines[number - 1], image, number, path)
        if image.image_id in images:
            first = images[image.image_id]
            raise SceneError(f"{path}: line {image.number}: image id {image.image_id} ({image.name}) is "
                             f"already used on line {first.number} ({first.name}); list each image once, "
                             "with its own IMAGE_ID")
        images[image.image_id] = image
    return images


def _image_line(f: list[str], n: int, path: Path) -> _ImageLine:
    try:
        if len(f) != 10:
            raise ValueError
        return _ImageLine(n, int(f[0]), np.array([float(x) for x in f[1:8]]), int(f[8]), f[9])
    except ValueError:
        raise SceneError(f"{path}: line {n} is not '{IMAGE_LINE}' ({len(f)} fields; 10 expected, "
                         "image names cannot contain spaces); fix the line") from None


def _check_points_line(line: str, image: _ImageLine, n: int, path: Path) -> None:
    """The 2D points line: triples ``X Y POINT3D_ID``; an image line here means a missing
    empty line, which would make COLMAP read that image as points."""
    f = line.split()
    if len(f) % 3 or not all(_reads_as(float, x) for x in f):
        raise SceneError(f"{path}: line {n} should be the 2D points of image {image.name} (X Y POINT3D_ID "
                         "..., may be empty) but is not; add an empty line after each image line")


def _reads_as(kind: type, text: str) -> bool:
    try:
        kind(text)
    except ValueError:
        return False
    return True


def _check_frames(files: dict[str, Path], images: dict[int, _ImageLine]) -> None:
    """Every image is in a frame of ``frames.txt``, taken by its own camera."""
    taken: dict[int, tuple[int, int]] = {}      # image id -> (camera id, line of frames.txt)
    for n, f in _data_lines(files["frames"]):
        try:
            data = f[10:10 + 3 * int(f[9])]
            for j in range(0, len(data), 3):
                if data[j] == "CAMERA":
                    taken[int(data[j + 2])] = (int(data[j + 1]), n)
        except (IndexError, ValueError):
            raise SceneError(f"{files['frames']}: line {n} is not 'FRAME_ID RIG_ID QW QX QY QZ TX TY TZ "
                             "NUM_DATA_IDS (SENSOR_TYPE SENSOR_ID DATA_ID)...'; fix it") from None
    for image in images.values():
        where = f"{files['images']}: line {image.number}: image {image.image_id} ({image.name})"
        if image.image_id not in taken:
            raise SceneError(f"{where} is in no frame of {files['frames'].name}; add it there, or delete "
                             "frames.txt and rigs.txt to take every pose from images.txt")
        camera, n = taken[image.image_id]
        if camera != image.camera_id:
            raise SceneError(f"{where} has camera {image.camera_id}, line {n} of {files['frames'].name} "
                             f"camera {camera}; make the two files agree")


def _check_poses_agree(rec, lines: dict[int, _ImageLine], files: dict[str, Path]) -> None:
    """pycolmap took the poses from frames.txt; images.txt must say the same."""
    import pycolmap
    for image in rec.images.values():
        line = lines[image.image_id]
        qw, qx, qy, qz = line.pose[:4]
        written = pycolmap.Rigid3d(pycolmap.Rotation3d(np.array([qx, qy, qz, qw])), line.pose[4:]).matrix()
        used = np.asarray(image.cam_from_world().matrix())
        if np.abs(written - used).max() > POSE_TOLERANCE * (1 + np.abs(used).max()):
            raise SceneError(f"{files['images']} (line {line.number}) and {files['frames']} give image "
                             f"{image.name} different poses; pycolmap takes the pose from frames.txt: make "
                             "the two agree, or delete frames.txt and rigs.txt to use images.txt alone")
