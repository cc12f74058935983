"""The schema of ``scene.yaml`` (``docs/scene-format.md``): a small typed reader written by hand.

:func:`read_scene_yaml` checks the whole file (YAML syntax, keys given twice, unknown keys,
types, ranges, unique segment names, Σ_kernels ρ ≤ 1) before the loader opens any mesh, image
or COLMAP file, and returns a :class:`SceneSpec` of checked values. Every problem raises
:class:`~framework.errors.SceneError` with one line naming the file, the key and the fix.
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from framework import kernels as kernel_registry
from framework.errors import SceneError
from framework.scene.model import CHANNELS, Photometry, Segment

# The keys of each mapping, in the order the docs list them: True for a required key.
TOP_KEYS = {"name": False, "channels": False, "segments": True, "emitters": True, "photometry": False}
SEGMENT_KEYS = {"name": True, "meshes": True, "kernels": False, "reference": False}
EMITTER_KEYS = {
    "constant": {"type": True, "radiance": True},
    "directional": {"type": True, "direction": True, "irradiance": True},
    "envmap": {"type": True, "file": True, "scale": False},
    "area": {"type": True, "meshes": True, "radiance": True},
}
EMITTER_TYPES = tuple(EMITTER_KEYS)
PHOTOMETRY_KEYS = {"encoding": False, "exposure": False, "reference_view": False, "saturation": False}
ENCODINGS = {"linear": "pixel values are radiance", "srgb": "8/16-bit camera output, decoded to linear"}
EXPOSURES = {"known": "pixel = radiance", "per_view": "one unknown gain per view and channel"}
DEFAULT_KERNELS = ("diffuse",)
# Σ ρ ≤ 1 up to the rounding of the 7 decimals scene.yaml is written with
SUM_TOLERANCE = 1e-9


@dataclass(frozen=True)
class EmitterSpec:
    """One checked emitter of scene.yaml; the loader reads its envmap and meshes later."""

    type: str
    radiance: np.ndarray | None = None       # constant, area: (C,)
    direction: np.ndarray | None = None      # directional: unit, the direction the light travels
    irradiance: np.ndarray | None = None     # directional: (C,)
    file: str | None = None                  # envmap, as written
    scale: float = 1.0                       # envmap
    meshes: tuple[str, ...] = ()             # area, as written


@dataclass(frozen=True)
class SceneSpec:
    """The checked content of scene.yaml."""

    path: Path                               # the scene.yaml read
    name: str | None
    channels: tuple[str, ...]
    segments: tuple[Segment, ...]
    emitters: tuple[EmitterSpec, ...]
    photometry: Photometry = field(default_factory=Photometry)


def one_line(text: object, limit: int = 160) -> str:
    """The first non-empty line of a foreign message (pycolmap, RPly, PyYAML), shortened.

    C++ check failures start with their source location (``[image.h:239] Check failed:``),
    which tells a user nothing; it is dropped.
    """
    lines = [line.strip() for line in str(text).splitlines() if line.strip()]
    line = lines[0] if lines else ""
    if line.startswith("[") and "]" in line:
        line = line.split("]", 1)[1].strip()
    line = line.removeprefix("Check failed:").strip()
    return line if len(line) <= limit else line[:limit - 3] + "..."


# ----------------------------------------------------------------------------------------------
# The file
# ----------------------------------------------------------------------------------------------

def read_scene_yaml(root: Path) -> SceneSpec:
    """Read and check ``root/scene.yaml`` completely.

    Parameters
    ----------
    root : Path
        The scene folder (resolved).

    Returns
    -------
    SceneSpec

    Raises
    ------
    SceneError
        One line naming the file, the key and the fix.
    """
    path = root / "scene.yaml"
    desc = _mapping(_load_yaml(root), TOP_KEYS, str(path))
    channels = _channels(desc.get("channels", "rgb"), f"{path}: channels")
    segments = tuple(_segment(s, i, path, channels) for i, s in enumerate(
        _list(desc["segments"], f"{path}: segments", "{name: ground, meshes: [meshes/ground.ply]}")))
    if not segments:
        raise SceneError(f"{path}: 'segments' is empty; list at least one segment")
    _unique_names(segments, path)
    emitters = tuple(_emitter(e, i, path, channels) for i, e in enumerate(
        _list(desc["emitters"], f"{path}: emitters", "{type: constant, radiance: 1.0}")))
    if not emitters:
        raise SceneError(f"{path}: no emitters; the illumination must be known: list at least one")
    name = _text(desc["name"], f"{path}: name") if "name" in desc else None
    photometry = _photometry(desc["photometry"], f"{path}: photometry") if "photometry" in desc else Photometry()
    return SceneSpec(path, name, channels, segments, emitters, photometry)


class _StrictLoader(yaml.SafeLoader):
    """PyYAML's safe loader, except that a key given twice in one mapping is an error (PyYAML
    keeps the last one silently, so a second ``kernels:`` would hide the first)."""

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":   # keys beside ``<<: *x`` override x's
                continue
            key = self.construct_object(key_node, deep=deep)
            try:
                twice = key in seen
                seen.add(key)
            except TypeError:               # an unhashable key: PyYAML's own check reports it
                continue
            if twice:
                raise yaml.constructor.ConstructorError(
                    None, None, f"key '{key}' is given twice in one mapping, keep one", key_node.start_mark)
        return super().construct_mapping(node, deep)


def _load_yaml(root: Path) -> object:
    path = root / "scene.yaml"
    if not root.is_dir():
        raise SceneError(f"{root}: scene directory does not exist; pass scene.dir=<folder with scene.yaml>")
    if not path.is_file():
        raise SceneError(f"{path}: missing; a scene folder needs scene.yaml (docs/scene-format.md)")
    try:
        return yaml.load(path.read_text(encoding="utf-8"), Loader=_StrictLoader)
    except UnicodeDecodeError:
        raise SceneError(f"{path}: is not valid YAML (not UTF-8 text); save it as UTF-8") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        problem = one_line(getattr(exc, "problem", None) or "syntax error")
        raise SceneError(f"{path}:{where} is not valid YAML ({problem}); fix the syntax") from None


# ----------------------------------------------------------------------------------------------
# Segments and emitters
# ----------------------------------------------------------------------------------------------

def _segment(s: object, i: int, path: Path, channels: tuple[str, ...]) -> Segment:
    named = isinstance(s, dict) and isinstance(s.get("name"), str) and s["name"]
    where = f"{path}: segment '{s['name']}'" if named else f"{path}: segment {i}"
    s = _mapping(s, SEGMENT_KEYS, where)
    name = _text(s["name"], f"{where} name")
    meshes = _names(s["meshes"], f"{where} meshes", "meshes/ground.ply",
                    empty=f"{where} has no meshes; list its PLY files")
    kernels = _kernels(s["kernels"], f"{where} kernels") if "kernels" in s else DEFAULT_KERNELS
    reference = _reference(s["reference"], kernels, channels, f"{where} reference") if "reference" in s else None
    return Segment(name, meshes, kernels, reference)


def _kernels(value: object, where: str) -> tuple[str, ...]:
    ks = _names(value, where, "diffuse", empty=f"{where} is empty; list at least one kernel, e.g. "
                                                 f"[diffuse] (leaving the key out means [diffuse])")
    try:
        ks = tuple(kernel_registry.canonical(k) for k in ks)      # glossy(0.150) is glossy(0.15)
    except SceneError as exc:
        raise SceneError(f"{where}: {exc}") from None
    twice = next((k for j, k in enumerate(ks) if k in ks[:j]), None)
    if twice is not None:
        raise SceneError(f"{where} lists the kernel '{twice}' twice: {list(ks)}; list each kernel once")
    return ks


def _reference(value: object, kernels: tuple[str, ...], channels, where: str) -> dict[str, np.ndarray]:
    if not isinstance(value, dict):
        raise SceneError(f"{where} must map the segment's kernels {list(kernels)} to weights, "
                         f"e.g. {{{kernels[0]}: 0.5}}; got {_shown(value)}")
    value = {_canonical_or_same(k): v for k, v in value.items()}
    ref = {k: _spectrum(v, channels, f"{where} {k}", unit=True)
           for k, v in _mapping(value, dict.fromkeys(kernels, False), where).items()}
    total = sum(ref.values(), np.zeros(len(channels)))
    c = int(np.argmax(total))
    if total[c] > 1 + SUM_TOLERANCE:
        raise SceneError(f"{where}: {' + '.join(ref)} = {total[c]:.6g} > 1 in channel {channels[c]}; a "
                         "segment's weights sum to at most 1 per channel (energy conservation): lower them")
    return ref


def _canonical_or_same(key: object) -> object:
    """A reference key as its kernel's canonical name, or unchanged when it names no kernel (the
    mapping check then reports it)."""
    try:
        return kernel_registry.canonical(str(key))
    except SceneError:
        return key


def _emitter(e: object, i: int, path: Path, channels: tuple[str, ...]) -> EmitterSpec:
    where = f"{path}: emitter {i}"
    if not isinstance(e, dict):
        raise SceneError(f"{where} must be a mapping with a type, e.g. {{type: constant, radiance: 1.0}}; "
                         f"got {_shown(e)}")
    t = e.get("type")
    if t not in EMITTER_TYPES:
        problem = f"type '{t}' unknown" if "type" in e else "has no type"
        raise SceneError(f"{where} {problem}; use one of {', '.join(EMITTER_TYPES)}")
    where = f"{where} ({t})"
    e = _mapping(e, EMITTER_KEYS[t], where)

    def spectrum(key: str) -> np.ndarray:
        return _spectrum(e[key], channels, f"{where} {key}", unit=False)

    if t == "constant":
        return EmitterSpec(t, radiance=spectrum("radiance"))
    if t == "directional":
        return EmitterSpec(t, direction=_direction(e["direction"], f"{where} direction"),
                           irradiance=spectrum("irradiance"))
    if t == "envmap":
        scale = _number(e.get("scale", 1.0), f"{where} scale", "a number >= 0")
        if not np.isfinite(scale) or scale < 0:
            raise SceneError(f"{where} scale = {scale} must be finite and >= 0 (it multiplies radiance)")
        return EmitterSpec(t, file=_text(e["file"], f"{where} file"), scale=scale)
    return EmitterSpec(t, meshes=_names(e["meshes"], f"{where} meshes", "meshes/light.ply",
                                        empty=f"{where} meshes is empty; list the PLY files that emit"),
                       radiance=spectrum("radiance"))


def _photometry(value: object, where: str) -> Photometry:
    """The ``photometry`` mapping: how the photographs encode radiance."""
    p = _mapping(value, PHOTOMETRY_KEYS, where)
    encoding = p.get("encoding")
    if "encoding" in p and encoding not in ENCODINGS:
        raise SceneError(f"{where} encoding {_quoted(encoding)} unknown; use "
                         + " or ".join(f"{k} ({v})" for k, v in ENCODINGS.items()))
    exposure = p.get("exposure", "known")
    if exposure not in EXPOSURES:
        raise SceneError(f"{where} exposure {_quoted(exposure)} unknown; use "
                         + " or ".join(f"{k} ({v})" for k, v in EXPOSURES.items()))
    reference = _text(p["reference_view"], f"{where} reference_view") if "reference_view" in p else None
    if exposure == "per_view" and reference is None:
        raise SceneError(f"{where} exposure per_view needs reference_view: add reference_view: <an image "
                         "name of images.txt>, the view whose gains are 1 (they fix the scale)")
    if exposure == "known" and reference is not None:
        raise SceneError(f"{where} reference_view is used only with exposure: per_view; add exposure: "
                         "per_view, or remove reference_view")
    saturation = None
    if "saturation" in p:
        saturation = _number(p["saturation"], f"{where} saturation", "a number in (0, 1]")
        if not 0 < saturation <= 1:
            raise SceneError(f"{where} saturation = {saturation:g} must lie in (0, 1] (a fraction of the "
                             "largest encoded value, e.g. 0.99; 1 ignores only pixels at the maximum)")
    return Photometry(encoding=encoding, exposure=exposure, reference_view=reference, saturation=saturation)


def _unique_names(segments: tuple[Segment, ...], path: Path) -> None:
    first: dict[str, int] = {}
    for i, seg in enumerate(segments):
        if seg.name in first:
            raise SceneError(f"{path}: segments {first[seg.name]} and {i} are both named '{seg.name}'; "
                             "give each segment its own name (they name the results)")
        first[seg.name] = i


# ----------------------------------------------------------------------------------------------
# Typed values
# ----------------------------------------------------------------------------------------------

def _mapping(value: object, keys: dict[str, bool], where: str) -> dict:
    """``value`` as a mapping with only ``keys`` and every required one; ``where`` begins the
    messages (``.../scene.yaml`` or ``.../scene.yaml: segment 'wall'``)."""
    allowed = ", ".join(keys)
    if not isinstance(value, dict):
        raise SceneError(f"{where} must be a mapping with keys {allowed}; got {_shown(value)}")
    for key in value:
        if key not in keys:
            close = difflib.get_close_matches(str(key), list(keys), n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise SceneError(f"{where}: unknown key '{key}'{hint}; allowed keys: {allowed}")
    missing = [k for k, required in keys.items() if required and k not in value]
    if missing:
        raise SceneError(f"{where} misses the required key '{missing[0]}'; add it "
                         f"(keys: {allowed}; docs/scene-format.md)")
    return value


def _list(value: object, where: str, example: str) -> list:
    if not isinstance(value, list):
        raise SceneError(f"{where} must be a list, e.g. [{example}]; got {_shown(value)}")
    return value


def _names(value: object, where: str, example: str, *, empty: str) -> tuple[str, ...]:
    """A non-empty list of non-empty strings (mesh paths, kernel names)."""
    items = _list(value, where, value if isinstance(value, str) and value else example)
    if not items:
        raise SceneError(empty)
    return tuple(_text(v, f"{where} item {j}") for j, v in enumerate(items))


def _text(value: object, where: str) -> str:
    if isinstance(value, str) and value and not value.strip():
        raise SceneError(f"{where} must be a non-empty string; got a blank string ({len(value)} "
                         f"whitespace character{'s' if len(value) > 1 else ''}, {value!r}): give it a name")
    if not isinstance(value, str) or not value.strip():
        raise SceneError(f"{where} must be a non-empty string; got {_shown(value)} (quote it if it "
                         "looks like a number)")
    return value


def _channels(value: object, where: str) -> tuple[str, ...]:
    if value not in CHANNELS:
        raise SceneError(f"{where} '{value}' unknown; use rgb or mono")
    return CHANNELS[value]


def _number(value: object, where: str, what: str) -> float:
    """A float; a string that reads as one is accepted because YAML 1.1 (PyYAML) reads ``1e3``,
    without a dot, as a string."""
    problem = SceneError(f"{where} must be {what}; got {_shown(value)}")
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise problem
    try:
        return float(value)
    except ValueError:
        raise problem from None


def _spectrum(value: object, channels: tuple[str, ...], where: str, *, unit: bool) -> np.ndarray:
    """One number or one per channel, as a (C,) array: a reflectance in [0, 1] (``unit``) or a
    radiance / irradiance >= 0."""
    what = f"a number or a list of {len(channels)} numbers"
    v = np.array([_number(x, where, what) for x in (value if isinstance(value, list) else [value])])
    if not isinstance(value, list):
        v = np.full(len(channels), v[0])
    if v.shape != (len(channels),):
        raise SceneError(f"{where} has {v.size} values; give one number or {len(channels)} "
                         f"(one per channel {','.join(channels)})")
    if not np.isfinite(v).all():
        raise SceneError(f"{where} = {v.tolist()} must be finite")
    if unit and (v.min() < 0 or v.max() > 1):
        raise SceneError(f"{where} = {v.tolist()} is outside [0, 1]; reflectances lie in [0, 1]")
    if v.min() < 0:
        raise SceneError(f"{where} = {v.tolist()} is negative; light is >= 0: fix the sign")
    return v


def _direction(value: object, where: str) -> np.ndarray:
    what = "3 finite numbers, not all 0 (the direction the light travels)"
    d = np.array([_number(x, where, what) for x in _list(value, where, "0.4, 0.3, -0.87")])
    if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) == 0:
        raise SceneError(f"{where} must be {what}; got {_shown(value)}")
    return d / np.linalg.norm(d)


def _quoted(value: object) -> str:
    """A value that should have been one of some names, for a message: 'gamma', or as shown."""
    return f"'{one_line(value, 60)}'" if isinstance(value, str) else _shown(value)


def _shown(value: object) -> str:
    """A short, one-line rendering of a YAML value for a message."""
    if value is None:
        return "nothing (null)"
    if isinstance(value, str):
        return f"the string '{one_line(value, 60)}'"
    if isinstance(value, dict):
        return "a mapping"
    return one_line(repr(value), 60)
