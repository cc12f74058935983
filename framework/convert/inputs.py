"""The converter's checks of its inputs, all made before anything is read in bulk or written.

Each raises :class:`~framework.errors.UserError` (an option) or
:class:`~framework.errors.SceneError` (a file) with one line naming the input and the fix:
the source's format (:func:`source_format`), ``OUT_DIR`` and the folders
(:func:`check_folders`), the emitters file (:func:`read_emitters`), the kernel options
(:func:`kernel_list`, :func:`segment_kernels`), and the frame of the COLMAP model against
the source's (:func:`check_frames`).
"""
from __future__ import annotations

import fnmatch
from pathlib import Path

import numpy as np
import yaml

from framework import brdf_kernels as kernel_registry
from framework.convert.model import SURVEY_LIMIT, Triangulated, origin_text
from framework.convert.ply import labels_file
from framework.errors import SceneError, UserError

#: suffix -> (format, the groupings it offers, its default grouping)
FORMATS = {
    ".obj": ("OBJ", ("material", "object"), "material"),
    ".gltf": ("glTF", ("material", "object"), "material"),
    ".glb": ("glTF", ("material", "object"), "material"),
    ".ply": ("PLY", ("material",), "material"),
    ".json": ("CityJSON", ("semantic", "object", "material"), "semantic"),
    ".jsonl": ("CityJSON", (), "semantic"),
}
#: Default kernels of CityJSON semantic surface types (others: ``--default-kernels``).
SEMANTIC_KERNELS = {"Window": ("diffuse", "specular")}
EMITTER_FILE_KEYS = ("emitters", "channels")
#: Characters that make a ``--kernels`` name a shell pattern.
PATTERN_CHARS = "*?["


def source_format(source: Path) -> tuple[str, tuple[str, ...], str]:
    """(format, its groupings, its default grouping) of the file ``source``."""
    if not source.is_file():
        raise UserError(f"{source}: no such file; give the mesh or city model to convert")
    if source.stat().st_size == 0:
        raise SceneError(f"{source}: is empty; export the mesh or city model again")
    suffix = source.suffix.lower()
    if suffix not in FORMATS or suffix == ".jsonl":
        raise UserError(f"{source}: unknown format '{source.suffix}'; convert an .obj, .gltf/.glb, .ply (with "
                        f"{labels_file(source).name}) or a CityJSON .json (CityJSONSeq .jsonl: cjio ... save first)")
    return FORMATS[suffix]


def check_folders(out_dir: Path, *, sparse: Path, images: Path | None, masks: Path | None) -> None:
    """The given folders exist; ``out_dir`` is new or empty, can be created, and lies outside the
    folders copied into it (``--images``, ``--masks``: a copy would then copy itself)."""
    given = {"--sparse": sparse, "--images": images, "--masks": masks}
    what = {"--sparse": "COLMAP model", "--images": "photographs", "--masks": "masks"}
    _check_out(out_dir)
    for option, folder in given.items():
        if folder is not None and not Path(folder).is_dir():
            raise UserError(f"{option} {folder}: no such folder; give the folder of the {what[option]}")
    for option in ("--images", "--masks"):
        folder = given[option] and Path(given[option]).resolve()
        if folder and (out_dir == folder or folder in out_dir.parents):
            raise UserError(f"OUT_DIR {out_dir} is inside {option} {folder}, which is copied into it; name the "
                            f"scene folder outside {folder}")


def _check_out(out_dir: Path) -> None:
    if out_dir.exists() and (not out_dir.is_dir() or any(out_dir.iterdir())):
        raise UserError(f"{out_dir}: exists and is not an empty folder; name a new folder for the scene")
    existing = next(p for p in out_dir.parents if p.exists())
    if not existing.is_dir():
        raise UserError(f"OUT_DIR {out_dir}: {existing} is a file, not a folder; name the scene folder elsewhere")
    if not out_dir.parent.is_dir():
        raise UserError(f"{out_dir.parent}: no such folder; create it, or name the scene folder elsewhere")


def read_emitters(path: Path) -> tuple[str, list]:
    """(channels, the ``emitters`` list) of the emitters file; scene.yaml's schema checks the
    list itself once the scene is staged (its messages then name this file)."""
    if not path.is_file():
        raise UserError(f"--emitters {path}: no such file; write a YAML file with an 'emitters:' list as in "
                        "scene.yaml (docs/scene-format.md)")
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError):
        raise SceneError(f"{path}: is not valid YAML; fix the syntax") from None
    if not isinstance(doc, dict) or "emitters" not in doc:
        raise SceneError(f"{path}: must be a mapping with an 'emitters:' list (as in scene.yaml) and optionally "
                         "'channels:'; add it")
    unknown = [k for k in doc if k not in EMITTER_FILE_KEYS]
    if unknown:
        raise SceneError(f"{path}: unknown key '{unknown[0]}'; allowed keys: {', '.join(EMITTER_FILE_KEYS)}")
    if not isinstance(doc["emitters"], list):
        raise SceneError(f"{path}: 'emitters' must be a list, e.g. [{{type: constant, radiance: 1.0}}]")
    area = [e for e in doc["emitters"] if isinstance(e, dict) and e.get("type") == "area"]
    if area:
        raise SceneError(f"{path}: area emitters name meshes of the scene folder; convert without them and add "
                         "them to the written scene.yaml")
    return doc.get("channels", "rgb"), doc["emitters"]


def kernel_list(value, where: str) -> tuple[str, ...]:
    """The canonical kernel names of ``value`` (``"diffuse,specular"`` or a sequence)."""
    names = [k.strip() for k in (value.split(",") if isinstance(value, str) else value)]
    if not names or not all(names):
        raise UserError(f"{where}: give a comma-separated list of kernels, e.g. diffuse,specular")
    try:
        out = tuple(kernel_registry.canonical(k) for k in names)
    except SceneError as exc:
        raise UserError(f"{where}: {exc}") from None
    if len(set(out)) != len(out):
        raise UserError(f"{where}: a kernel is listed twice ({','.join(out)}); list each once")
    return out


def segment_kernels(parts: list[Triangulated], kernels: dict, default: tuple[str, ...],
                    source: Path) -> dict[str, tuple[str, ...]]:
    """Each segment's kernels: the ``kernels`` entry of its very name, else the first entry whose
    shell pattern matches it, else its semantic type's default, else ``default``. An entry
    matching no segment is an error listing them."""
    names = [p.name for p in parts]
    for entry in kernels:
        if entry not in names and not any(fnmatch.fnmatchcase(n, entry) for n in names):
            shown = ", ".join(names[:30]) + (f", ... ({len(names)} segments)" if len(names) > 30 else "")
            literal = ("; as a shell pattern, * and ? are wildcards and '[...]' in a pattern is a set of characters: "
                       "write [[] for a literal '[' ([*], [?] for '*', '?')") if set(entry) & set(PATTERN_CHARS) else ""
            raise UserError(f"--kernels {entry}=...: no segment of {source.name} is named so; segments: {shown}"
                            f"{literal}")
    out = {}
    for p in parts:
        match = kernels.get(p.name) or next((k for pat, k in kernels.items() if fnmatch.fnmatchcase(p.name, pat)), None)
        out[p.name] = match or SEMANTIC_KERNELS.get(p.semantic or "", default)
    return out


def check_frames(model, origin: np.ndarray, *, source: Path, sparse: Path) -> None:
    """Refuse a COLMAP model in a local frame (every camera within :data:`SURVEY_LIMIT` of 0)
    beside a source in survey coordinates (``origin`` not 0): after the move by ``-origin`` its
    cameras would lie thousands of kilometres from the geometry."""
    if not np.any(origin) or not model.cameras:
        return
    poses = [np.asarray(c.cam_from_world, np.float64) for c in model.cameras]
    if max(np.abs(T[:, :3].T @ T[:, 3]).max() for T in poses) <= SURVEY_LIMIT:      # |camera centre|
        raise SceneError(f"{sparse}: every camera lies within 1 km of 0 (a local frame) while {source.name} is in "
                        f"survey coordinates (origin {origin_text(origin)}); give --sparse in the frame of "
                        f"{source.name} (georeference the model, e.g. colmap model_aligner), or convert a mesh in "
                        "the model's local frame")
