"""From a labelled mesh or a city model to a scene folder (``docs/convert.md``).

:func:`convert` reads the source with its format's reader, triangulates it
(:func:`~framework.convert.model.triangulate`), moves the meshes and the COLMAP model together to
a local origin (float64), and writes the folder with :mod:`framework.scene.write` into a hidden
staging folder beside ``out_dir``. It then loads the staged folder as a run would
(:func:`framework.scene.load_scene`) and runs the blind-view check (some camera must see some
segment) before moving it into place: on any error nothing is left behind.
"""
from __future__ import annotations

import hashlib
import os
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from framework.convert.cityjson import read_cityjson
from framework.convert.gltf import read_gltf
from framework.convert.inputs import (check_folders, check_frames, kernel_list, read_emitters, segment_kernels,
                                      source_format)
from framework.convert.model import Triangulated, local_origin, moved, origin_text, triangulate
from framework.convert.obj import read_obj
from framework.convert.ply import read_ply
from framework.errors import SceneError, UserError
from framework.scene.colmap import read_model
from framework.scene.write import write_colmap, write_mesh, write_scene_yaml

@dataclass
class Conversion:
    """What :func:`convert` wrote."""

    folder: Path
    origin: np.ndarray                      # survey coordinates of the folder's (0, 0, 0)
    segments: dict[str, tuple[str, ...]]    # segment -> kernels, in scene.yaml order
    triangles: int
    dropped: int                            # degenerate faces and polygons dropped
    views: int
    warnings: list[str] = field(default_factory=list)   # one line each; the command line prints them


def convert(source: str | os.PathLike, out_dir: str | os.PathLike, *, sparse: str | os.PathLike,
            emitters: str | os.PathLike, images: str | os.PathLike | None = None,
            masks: str | os.PathLike | None = None, group: str | None = None,
            kernels: dict[str, tuple[str, ...]] | None = None,
            default_kernels: tuple[str, ...] = ("diffuse",), check_views: bool = True) -> Conversion:
    """Convert ``source`` into the scene folder ``out_dir``.

    Parameters
    ----------
    source : path-like
        ``.obj``, ``.gltf``/``.glb``, ``.ply`` (with ``<stem>.labels.yaml`` beside it) or a
        CityJSON ``.json`` (``.city.json``).
    out_dir : path-like
        The scene folder to write; must not exist, or be empty.
    sparse : path-like
        The COLMAP model (text or binary) of the photographs, in the frame of ``source``.
    emitters : path-like
        A YAML file with an ``emitters:`` list as in scene.yaml and optionally ``channels:``
        (``rgb``, the default, or ``mono``); an ``envmap`` file is read beside it and copied.
    images, masks : path-like, optional
        Folders copied to ``images/`` and ``masks/`` (the photographs, named as in the model).
    group : str, optional
        ``material``, ``object`` or ``semantic``; the default depends on the format (material;
        semantic for CityJSON).
    kernels : dict, optional
        Segment name or shell pattern (``*/Window``) -> kernels, overriding the defaults; an
        entry that is a segment's very name wins over the patterns that match it.
    default_kernels : tuple of str, default ("diffuse",)
        Kernels of a segment that no ``kernels`` entry and no semantic default (CityJSON
        ``Window``: diffuse, specular) gives kernels to.
    check_views : bool, default True
        Load the written folder and run the blind-view check (Mitsuba: a ray per pixel).

    Returns
    -------
    Conversion
        Its ``warnings`` (materials without faces, degenerate faces dropped, unused PLY labels)
        are for the caller to show; the command line prints them as ``warning: ...`` lines.

    Raises
    ------
    SceneError, UserError
        One line naming the input and the fix; nothing is written then.
    """
    source, out_dir, sparse, emitters_path = (Path(p).expanduser().resolve() for p in (source, out_dir, sparse, emitters))
    fmt, groups, default_group = source_format(source)
    group = group or default_group
    if group not in groups:
        raise UserError(f"--group {group} does not apply to {fmt} ({source.name}); use "
                        f"{' or '.join(groups)}")
    check_folders(out_dir, sparse=sparse, images=images, masks=masks)
    channels, emitter_list = read_emitters(emitters_path)
    default_kernels = kernel_list(default_kernels, "--default-kernels")
    kernels = {k: kernel_list(v, f"--kernels {k}") for k, v in (kernels or {}).items()}
    warnings: list[str] = []

    src, facts = _read(source, fmt, group)
    parts, dropped = triangulate(src)
    warnings += src.warnings
    if dropped:
        warnings.append(f"{source}: dropped {dropped} degenerate face(s) or polygon(s) (fewer than 3 distinct "
                        "vertices, or no area)")
    origin = local_origin(parts)
    parts = moved(parts, origin)
    kernels_of = segment_kernels(parts, kernels, default_kernels, source)
    model = read_model(sparse.parent, sparse=sparse)
    check_frames(model, origin, source=source, sparse=sparse)

    staging = out_dir.parent / f".{out_dir.name}.partial-{os.getpid()}"
    if staging.exists():
        shutil.rmtree(staging)
    try:
        files = _write_meshes(staging, parts)
        _write_cameras(staging, sparse, model, origin)
        for folder, name in ((images, "images"), (masks, "masks")):
            if folder is not None:
                shutil.copytree(folder, staging / name)
        emitter_list = _copy_envmaps(emitter_list, emitters_path, staging)
        scene = {"name": out_dir.name, "channels": channels, "origin": origin.tolist(),
                 "segments": [{"name": p.name, "meshes": [files[p.name]], "kernels": list(kernels_of[p.name])}
                              for p in parts],
                 "emitters": emitter_list}
        digest = _sha256(source)
        write_scene_yaml(staging / "scene.yaml", scene, _comment(source, digest, fmt, group, origin))
        _write_readme(staging, source, digest, fmt, group, origin, facts, parts, dropped, sparse)
        if check_views:
            given = {"images": images, "masks": masks}
            _check(staging, out_dir, source, sparse, origin, emitters_path, observations=images is not None,
                   copied={staging / k: Path(v).resolve() for k, v in given.items() if v is not None})
        if out_dir.exists():
            out_dir.rmdir()
        staging.rename(out_dir)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return Conversion(out_dir, origin, kernels_of, int(sum(len(p.faces) for p in parts)), dropped,
                      len(model.cameras), warnings)


# ----------------------------------------------------------------------------------------------
# Inputs
# ----------------------------------------------------------------------------------------------

def _read(source: Path, fmt: str, group: str):
    if fmt == "OBJ":
        return read_obj(source, group), {}
    if fmt == "glTF":
        return read_gltf(source, group), {}
    if fmt == "PLY":
        return read_ply(source), {}
    return read_cityjson(source, group)


# ----------------------------------------------------------------------------------------------
# Writing
# ----------------------------------------------------------------------------------------------

def _slug(name: str) -> str:
    parts = [re.sub(r"[^A-Za-z0-9._-]+", "_", p).strip(".") or "_" for p in name.split("/")]
    return "/".join(parts)


def _write_meshes(staging: Path, parts: list[Triangulated]) -> dict[str, str]:
    """One PLY per segment, ``meshes/<segment>.ply`` (``/`` in a name makes a sub-folder)."""
    files, taken = {}, set()
    for p in parts:
        stem, n = _slug(p.name), 1
        while (stem if n == 1 else f"{stem}~{n}").lower() in taken:
            n += 1
        stem = stem if n == 1 else f"{stem}~{n}"
        taken.add(stem.lower())
        rel = f"meshes/{stem}.ply"
        write_mesh(staging / rel, p.vertices, p.faces)
        files[p.name] = rel
    return files


def _write_cameras(staging: Path, sparse: Path, model, origin: np.ndarray) -> None:
    """The COLMAP model moved by ``-origin``: t' = t + R·origin (float64), delivered cameras kept."""
    import pycolmap
    from dataclasses import replace

    cams = []
    for c in model.cameras:
        T = np.asarray(c.cam_from_world, np.float64)
        cams.append(replace(c, cam_from_world=np.concatenate([T[:, :3], (T[:, 3] + T[:, :3] @ origin)[:, None]], 1)))
    rec = pycolmap.Reconstruction(str(sparse))
    points = np.array([p.xyz for p in rec.points3D.values()], np.float64).reshape(-1, 3) - origin
    write_colmap(staging / "sparse", cams, points, models=[c.distortion for c in cams])


def _copy_envmaps(emitters: list, emitters_path: Path, staging: Path) -> list:
    out = []
    for e in emitters:
        if isinstance(e, dict) and e.get("type") == "envmap" and isinstance(e.get("file"), str):
            src = (emitters_path.parent / e["file"]).resolve()
            if not src.is_file():
                raise SceneError(f"{emitters_path}: envmap file {e['file']} not found beside it; fix the path")
            shutil.copy2(src, staging / src.name)
            e = {**e, "file": src.name}
        out.append(e)
    return out


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _comment(source: Path, digest: str, fmt: str, group: str, origin: np.ndarray) -> str:
    return (f"Converted by `python -m framework.convert` from {source.name} ({fmt}, --group {group}),\n"
            f"sha256 {digest}; see README.md beside this file.\n"
            f"origin: the survey coordinates of this folder's (0, 0, 0); meshes and cameras were moved by\n"
            f"-origin = -{origin_text(origin)} (float64).")


def _write_readme(staging: Path, source: Path, digest: str, fmt: str, group: str, origin: np.ndarray,
                  facts: dict, parts: list[Triangulated], dropped: int, sparse: Path) -> None:
    crs = facts.get("referenceSystem")
    lines = ["# Converted scene", "",
             "Written by `python -m framework.convert` (docs/convert.md).", "",
             "| item | value |", "|---|---|",
             f"| source | `{source.name}` ({fmt}{', version ' + facts['version'] if 'version' in facts else ''}) |",
             f"| source sha256 | `{digest}` |",
             f"| grouping | `--group {group}` |",
             f"| COLMAP model | `{sparse.name}/`, moved with the meshes |",
             f"| origin | `{origin_text(origin)}`{' in ' + str(crs) if crs else ''}: the survey coordinates of this folder's (0, 0, 0) |",
             f"| segments | {len(parts)} |",
             f"| triangles | {sum(len(p.faces) for p in parts)} |",
             f"| degenerate faces dropped | {dropped} |", "",
             "A point of this folder at (x, y, z) lies at origin + (x, y, z) in the source's coordinates.", ""]
    (staging / "README.md").write_text("\n".join(lines), encoding="utf-8")


# ----------------------------------------------------------------------------------------------
# The check
# ----------------------------------------------------------------------------------------------

def _check(staging: Path, out_dir: Path, source: Path, sparse: Path, origin: np.ndarray, emitters_path: Path,
           *, observations: bool, copied: dict[Path, Path]) -> None:
    """Load the staged folder (as a run would) and check that some view sees some segment.

    Messages name the user's files: the emitters file for an emitter, the ``--images`` and
    ``--masks`` folders for the copies (``copied``: staged folder -> given folder), ``out_dir``
    for the rest; the blind-view check's poses are those of ``sparse``, the model the user can fix
    (the staged one is moved and renumbered)."""
    from framework.render import backend
    from framework.render.checks import check_lit_and_seen
    from framework.scene import load_scene

    def renamed(text: str) -> str:
        text = text.replace(str(staging / "scene.yaml"), str(emitters_path)) if "emitter" in text else text
        for staged, given in copied.items():
            text = text.replace(str(staged), str(given))
        return text.replace(str(staging), str(out_dir))

    try:
        scene = load_scene(staging, observations=observations)
    except SceneError as exc:
        raise SceneError(renamed(str(exc))) from None
    backend.set_variant("auto", channels=scene.channels)
    try:
        check_lit_and_seen(scene, list(scene.cameras), views_option=False)
    except SceneError as exc:
        text = renamed(str(exc).replace(str(staging / "sparse"), str(sparse)))
        raise SceneError(f"{sparse}: after the move to the local origin {origin_text(origin)}, {text} "
                         f"(is the COLMAP model in the frame of {source.name}?)") from None
