"""The run folder: who may write it (:class:`RunFolder`), results.json (``docs/results.md``)
and the images."""
from __future__ import annotations

import json
import logging
import math
import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import numpy as np

from framework.cache import atomic_write_bytes
from framework.errors import ConfigError
from framework.images import write_exr
from framework.registry import MethodResult, Problem

log = logging.getLogger(__name__)

RESULTS_NAME = "results.json"
#: What a run writes into its folder besides Hydra's ``.hydra/`` and ``<job>.log``: a failed
#: run removes these names only, so a file someone else put there meanwhile survives.
OUTPUT_NAMES = ("images", "report.md", "report.html", "report_files", RESULTS_NAME)
HYDRA_NAMES = (".hydra",)


def _inside(path: Path, folder: Path) -> bool:
    """Whether ``path`` is ``folder`` or below it (symbolic links resolved)."""
    return path.resolve().is_relative_to(folder.resolve())


def _foreign_reason(foreign: list[str]) -> str:
    """Why a run folder holding ``foreign`` entries is not this run's to write."""
    if "scene.yaml" in foreign:
        return "holds a scene (scene.yaml), which runs never write to"
    if RESULTS_NAME in foreign:
        return f"holds an earlier run ({RESULTS_NAME})"
    shown = ", ".join(foreign[:3]) + (", ..." if len(foreign) > 3 else "")
    return f"already holds files ({shown})"


@dataclass(frozen=True)
class RunFolder:
    """The folder of one run, checked before anything is written into it.

    A failed run calls :meth:`discard`, which removes what this run writes (``OUTPUT_NAMES``,
    Hydra's files) and the folder itself if the run created it, never anything else: the folder
    is refused up front when it holds anything else (:meth:`claim`).
    """

    path: Path
    existed: bool
    log_name: str = "run.log"

    @classmethod
    def claim(cls, path, *, scene_root, key: str = "hydra.run.dir", hydra_written=(),
              log_name: str = "run.log") -> RunFolder:
        """The run folder ``path``, if this run may write it: new, empty, or holding only the
        ``hydra_written`` entries.

        The command line claims the folder before Hydra starts (``hydra_written`` empty); a
        sweep job can only be checked once Hydra has created its folder and written ``.hydra/``
        and the log into it: those are ``hydra_written``, and the folder counts as this run's.

        Raises
        ------
        ConfigError
            If a part of ``path`` (or of the files Hydra writes in it) is longer than the file
            system allows (:func:`check_path_length`), if ``path`` is a file, lies in the scene folder ``scene_root``, or holds anything
            else (a scene, an earlier run, other files); the message names ``key``, the setting
            that chose the folder.
        """
        path = Path(os.path.abspath(path))      # as Hydra names it (runtime.output_dir)
        shown = str(path) if len(str(path)) <= 80 else f"{str(path)[:60]}...{str(path)[-16:]}"
        check_path_length(path / ".hydra" / "overrides.yaml", f"run folder {shown} ({key})",
                          f"choose a shorter {key}")
        where = f"run folder {path} ({key})"
        if _inside(path, Path(scene_root)):
            raise ConfigError(f"{where} is inside the scene folder {Path(scene_root).resolve()}, "
                              "which runs never write to: choose a run folder outside it")
        if path.exists() and not path.is_dir():
            raise ConfigError(f"{where} is a file: choose a new or empty folder")
        foreign = sorted(e.name for e in path.iterdir() if e.name not in hydra_written) if path.is_dir() else []
        if foreign:
            raise ConfigError(f"{where} {_foreign_reason(foreign)}: choose a new or empty folder, "
                              "so that this run's files cannot mix with others")
        return cls(path, path.is_dir() and not hydra_written, log_name)

    def discard(self) -> None:
        """Remove what this run wrote, after a failure; keep a finished run (results.json)."""
        if not self.path.is_dir() or (self.path / RESULTS_NAME).exists():
            return
        for name in (*OUTPUT_NAMES, *HYDRA_NAMES, self.log_name):
            entry = self.path / name
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry, ignore_errors=True)
            else:
                entry.unlink(missing_ok=True)
        if not self.existed:
            try:
                self.path.rmdir()         # only when empty: anything added meanwhile stays
            except OSError:
                pass


def image_paths(names) -> dict[str, str]:
    """A path below ``images/`` for each image name, unique, that stays in the run folder.

    Image names come from the scene's ``images.txt`` and may hold sub-folders (kept:
    ``left/top_000.png``); empty, ``.`` and leading ``/`` parts are dropped, ``..`` parts
    become ``__`` and control characters ``_``, so no name writes outside ``images/``.
    results.json keeps the original names.
    """
    out, used = {}, set()
    for name in names:
        parts = [p for p in re.split(r"[\\/]+", str(name)) if p not in ("", ".")]
        base = "/".join("__" if p == ".." else re.sub(r"[\x00-\x1f]", "_", p) for p in parts) or "view"
        stem, n = base, 1
        while stem.casefold() in used:           # two names made equal (or equal but for case)
            n += 1
            stem = f"{base}~{n}"
        used.add(stem.casefold())
        out[name] = f"images/{stem}"
    return out


def _target(run_dir: Path, rel: str) -> Path:
    """``run_dir / rel`` with its folder created (image names may hold sub-folders)."""
    path = run_dir / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def per_channel(row: np.ndarray) -> list | None:
    """One number per channel, None for NaN (unknown) entries; None if all unknown."""
    if row is None or np.all(np.isnan(row)):
        return None
    return [None if np.isnan(x) else float(x) for x in row]


def parameter_rows(problem: Problem, result: MethodResult) -> list[dict]:
    params = result.parameters or problem.parameters
    ref = problem.scene.reference(params)
    ill = result.extras.get("ill_determined")       # (P,) bools, from methods with a std
    why = result.extras.get("ill_determined_why")   # (P,) reasons of a poor fit, or None
    rows = []
    for p in params:
        est = result.estimate[p.index]
        observable = True if result.observable is None else bool(result.observable[p.index])
        row = {"segment": p.segment_name, "kernel": p.kernel,
               "estimate": per_channel(est) if observable else None,
               "reference": per_channel(ref[p.index]),
               "error": per_channel(est - ref[p.index]) if observable else None}
        if result.std is not None:
            row["std"] = per_channel(result.std[p.index]) if observable else None
        if result.observable is not None:
            row["observable"] = observable
        if ill is not None:
            row["ill_determined"] = bool(ill[p.index])
        if why is not None and why[p.index]:
            row["why"] = str(why[p.index])
        if _known(problem.scene, p):
            row["known"] = True          # held at scene.yaml's value: estimate = it, std 0
        rows.append(row)
    return rows


def _known(scene, p) -> bool:
    """Whether parameter ``p`` is a weight scene.yaml holds fixed (its segment's ``known``)."""
    known = getattr(scene.segments[p.segment], "known", None) if 0 <= p.segment < len(scene.segments) else None
    return bool(known) and p.kernel in known


def used_pixels(problem: Problem, result: MethodResult, name: str) -> np.ndarray | None:
    """``(H, W)`` bool: the pixels of view ``name`` the fit used, i.e. of non-zero weight in the
    scene (masks, saturated and black pixels of photographs left out) and in the method's final
    fit (``MethodResult.pixel_weights``: boundary pixels, robust weights of exactly 0); None when
    every pixel counts."""
    used = None
    for weights in ((problem.weights or {}).get(name), (result.pixel_weights or {}).get(name)):
        if weights is not None:
            w = np.asarray(weights) > 0
            used = w if used is None else used & w
    return used


def image_rmse(problem: Problem, result: MethodResult) -> float | None:
    """RMSE over the pixels the fit used (:func:`used_pixels`) and every channel of every view
    with a reconstruction: a masked pixel, whose observation is 0, does not count against the
    reconstruction. None when no view has a reconstruction or no pixel was used."""
    sq, n = 0.0, 0
    for name, rec in result.reconstructions.items():
        d = rec.astype(float) - problem.observed[name]
        used = used_pixels(problem, result, name)
        if used is not None:
            d = d[used]
        sq, n = sq + float((d * d).sum()), n + d.size
    return float(np.sqrt(sq / n)) if n else None


#: The longest names a run derives from an image name ``<name>``: ``images/<name>.reconstruction.exr``
#: and, in the report, ``report_files/view<NNN>_<name>_reconstruction.png``.
IMAGE_SUFFIX = ".reconstruction.exr"
REPORT_NAME_EXTRA = len("view000_") + len("_reconstruction.png")
NAME_MAX, PATH_MAX = 255, 4096            # Linux's; the file system's own where it says


def fs_limits(path: Path) -> tuple[int, int]:
    """``(NAME_MAX, PATH_MAX)`` in bytes of the file system holding ``path`` (its nearest
    existing folder), Linux's 255 and 4096 where it does not say."""
    folder = Path(os.path.abspath(path))
    while not os.path.isdir(folder) and folder != folder.parent:     # isdir: False on ENAMETOOLONG
        folder = folder.parent
    limits = []
    for key, default in (("PC_NAME_MAX", NAME_MAX), ("PC_PATH_MAX", PATH_MAX)):
        try:
            limits.append(int(os.pathconf(folder, key)) or default)
        except (OSError, ValueError):
            limits.append(default)
    return limits[0], limits[1]


def check_path_length(path: Path, what: str, fix: str) -> None:
    """ConfigError when a part of ``path`` is longer than the file system's NAME_MAX bytes or
    the whole longer than its PATH_MAX (checked before anything is written: the OS refuses
    such a name only once a file is created)."""
    name_max, path_max = fs_limits(path)
    path = Path(os.path.abspath(path))
    for part in path.parts:
        size = len(os.fsencode(part))
        if size > name_max:
            shown = part if len(part) <= 40 else part[:37] + "..."
            raise ConfigError(f"{what}: its part '{shown}' is {size} bytes, more than the {name_max} this "
                              f"file system allows in one name: {fix}")
    size = len(os.fsencode(str(path)))
    if size >= path_max:
        raise ConfigError(f"{what} is {size} bytes long, more than the {path_max - 1} this file system "
                          f"allows in a path: {fix}")


def check_output_names(run_dir: Path, names) -> None:
    """Every file the run will write for the image ``names`` fits the file system's limits
    (:func:`check_path_length`), checked before the work starts: a 249-byte COLMAP image name
    would otherwise fail only when the images are written, after every rendering.

    Raises
    ------
    ConfigError
        Naming the image and the file, with the fix.
    """
    run_dir = Path(os.path.abspath(run_dir))
    name_max, _ = fs_limits(run_dir)
    for name, rel in image_paths(names).items():
        fix = "rename the image in the COLMAP model, or leave it out (views=...)"
        if len(os.fsencode(PurePosixPath(rel).name)) + REPORT_NAME_EXTRA > name_max:
            raise ConfigError(f"image name '{name[:40]}...' ({len(os.fsencode(name))} bytes) is too long for the "
                              f"files the run names after it (images/<name>{IMAGE_SUFFIX}, "
                              f"report_files/view000_<name>_reconstruction.png): the file system allows "
                              f"{name_max} bytes per name, so at most {name_max - REPORT_NAME_EXTRA}; {fix}")
        check_path_length(run_dir / f"{rel}{IMAGE_SUFFIX}", f"the run's file {rel}{IMAGE_SUFFIX} for image "
                          f"'{name[:40]}'", fix + ", or choose a shorter run folder (hydra.run.dir)")


def write_view_images(run_dir: Path, problem: Problem, result: MethodResult, segment_maps: dict) -> list[dict]:
    """Observed / reconstruction EXRs and segment maps under ``images/``; their entries for results.json."""
    entries = []
    (run_dir / "images").mkdir(parents=True, exist_ok=True)
    paths = image_paths(c.name for c in problem.cameras)
    for cam in problem.cameras:
        base = paths[cam.name]
        write_exr(_target(run_dir, f"{base}.observed.exr"), problem.observed[cam.name], problem.scene.channels)
        entry = {"name": cam.name, "observed": f"{base}.observed.exr", "reconstruction": None, "segments": None}
        if cam.name in result.reconstructions:
            write_exr(run_dir / f"{base}.reconstruction.exr", result.reconstructions[cam.name],
                      problem.scene.channels)
            entry["reconstruction"] = f"{base}.reconstruction.exr"
        weights = (result.pixel_weights or {}).get(cam.name)
        if weights is not None:                 # the fit's weight of each pixel (robust, masks)
            write_exr(run_dir / f"{base}.weights.exr", np.asarray(weights, np.float32)[..., None], ("Y",))
            entry["weights"] = f"{base}.weights.exr"
        reasons = (result.pixel_reasons or {}).get(cam.name)
        if reasons is None:
            reasons = (getattr(problem.scene, "excluded", None) or {}).get(cam.name)
        if reasons is not None:                 # why each pixel was left out
            entry.update(excluded_entry(run_dir, base, reasons))
        if cam.name in segment_maps:
            np.save(run_dir / f"{base}.segments.npy", segment_maps[cam.name].astype(np.int32))
            entry["segments"] = f"{base}.segments.npy"
        entries.append(entry)
    return entries


def excluded_entry(run_dir: Path, base: str, reasons: np.ndarray) -> dict:
    """Write ``<base>.excluded.png`` (8-bit codes of ``EXCLUSION_REASONS``, 0: used) and return
    the view's ``excluded`` (pixels per reason, the reasons that occur) and ``excluded_map``."""
    from PIL import Image

    from framework.scene.model import EXCLUSION_REASONS
    codes = np.asarray(reasons, np.uint8)
    Image.fromarray(codes).save(run_dir / f"{base}.excluded.png")
    counts = np.bincount(codes.ravel(), minlength=len(EXCLUSION_REASONS))
    return {"excluded": {r: int(n) for r, n in zip(EXCLUSION_REASONS[1:], counts[1:]) if n},
            "excluded_map": f"{base}.excluded.png"}


def write_relit_images(run_dir: Path, problem: Problem, result: MethodResult) -> list[dict]:
    """Relit and reflectance images a method returned in ``extras["relit_images"]`` (popped):
    EXRs under ``images/`` and the ``relit`` entries of results.json."""
    images = result.extras.pop("relit_images", None) or {}
    entries = []
    paths = image_paths(images)
    for name, image in images.items():
        path = f"{paths[name]}.exr"
        write_exr(_target(run_dir, path), image, problem.scene.channels)
        entries.append({"name": name, "image": path})
    return entries


def results_dict(problem: Problem, result: MethodResult, *, method: str, settings: dict,
                 views: list[dict], relit: list[dict]) -> dict:
    return {
        "method": method,
        "scene": problem.scene.name,
        "origin": None if problem.scene.origin is None else list(problem.scene.origin),
        "channels": list(problem.scene.channels),
        "parameters": parameter_rows(problem, result),
        "timings_s": {k: float(v) for k, v in result.timings_s.items()},
        "renders": int(result.renders),
        "cost_history": [float(c) for c in result.cost_history],
        "cost_times_s": [float(t) for t in result.cost_times_s],
        "trace": result.trace,
        "image_rmse": image_rmse(problem, result),
        "settings": settings,
        "segments": [s.name for s in problem.scene.segments],
        "views": views,
        "relit": relit,
        "views_left_out": [{"name": n, "reason": why} for n, why in problem.views_left_out.items()],
        **result.extras,
    }


def write_results(run_dir: Path, results: dict) -> Path:
    """Write results.json atomically: it appears whole or not at all.

    A non-finite number (NaN, ±inf) is written as null, as docs/results.md says, with a warning
    naming where it was: JSON has no such numbers, and a run that computed one should say so.
    """
    path = Path(run_dir) / RESULTS_NAME
    found: list[str] = []
    clean = finite_json(results, "", found)
    if found:
        shown = ", ".join(found[:5]) + (f" and {len(found) - 5} more" if len(found) > 5 else "")
        log.warning("results.json: non-finite numbers written as null at %s", shown)
    atomic_write_bytes(path, (json.dumps(clean, indent=2, allow_nan=False) + "\n").encode())
    return path


def finite_json(value, where: str, found: list[str]):
    """``value`` with every non-finite float replaced by None; their places appended to ``found``."""
    if isinstance(value, dict):
        return {k: finite_json(v, f"{where}.{k}" if where else str(k), found) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(v, f"{where}[{i}]", found) for i, v in enumerate(value)]
    if isinstance(value, (float, np.floating)):
        if not math.isfinite(value):
            found.append(where)
            return None
        return float(value)
    return value
