"""The schema of ``scene.yaml`` (``docs/scene-format.md``): a small typed reader written by hand.

:func:`read_scene_yaml` checks the whole file (YAML syntax, keys given twice, unknown keys,
types, ranges, unique segment names, Σ_kernels ρ ≤ 1) before the loader opens any mesh, image
or COLMAP file, and returns a :class:`SceneSpec` of checked values. Every problem raises
:class:`~framework.errors.SceneError` with one line naming the file, the key and the fix.
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from datetime import date, datetime
from pathlib import Path

import numpy as np
import yaml

from framework import kernels as kernel_registry
from framework.errors import SceneError
from framework.scene.model import CHANNELS, Photometry, Segment

# The keys of each mapping, in the order the docs list them: True for a required key.
TOP_KEYS = {"name": False, "channels": False, "origin": False, "segments": True, "emitters": True,
            "photometry": False}
SEGMENT_KEYS = {"name": True, "meshes": True, "kernels": False, "reference": False, "known": False}
EMITTER_KEYS = {
    "constant": {"type": True, "radiance": True, "scale": False},
    "directional": {"type": True, "direction": True, "irradiance": True, "scale": False},
    "envmap": {"type": True, "file": True, "scale": False},
    "area": {"type": True, "meshes": True, "radiance": True, "scale": False},
    "sunsky": {"type": True, "latitude": False, "longitude": False, "time": False, "sun_direction": False,
               "turbidity": False, "ground_albedo": False, "north": False, "sun_scale": False,
               "sky_scale": False},
}
EMITTER_TYPES = tuple(EMITTER_KEYS)
UNKNOWN = "unknown"                      # the word that makes an emitter's scale an unknown
PLACE_AND_TIME = ("latitude", "longitude", "time")
#: a sunsky's ``north`` may leave the horizontal plane by this much (its sine); it is projected on it
NORTH_TILT_MAX_DEG = 5.0
PHOTOMETRY_KEYS = {"encoding": False, "exposure": False, "reference_view": False, "saturation": False,
                   "vignetting": False}
VIGNETTING = {"none": "no lens falloff", "estimate": "one unknown profile per camera",
              "[a1, a2, a3]": "a known profile"}
ENCODINGS = {"linear": "pixel values are radiance", "srgb": "8/16-bit camera output, decoded to linear"}
EXPOSURES = {"known": "pixel = radiance", "per_view": "one unknown gain per view and channel"}
DEFAULT_KERNELS = ("diffuse",)
# Σ ρ ≤ 1 up to the rounding of the 7 decimals scene.yaml is written with
SUM_TOLERANCE = 1e-9


@dataclass(frozen=True)
class SunskySpec:
    """A checked ``sunsky`` emitter: where and when (or the sun's direction) and the atmosphere.

    Exactly one of (``latitude``, ``longitude``, ``time``) and ``sun_direction`` is given; the
    loader computes the sun's direction from the first (:func:`framework.render.sunsky.sun_position`).
    """

    latitude: float | None = None            # degrees, north positive, in [-90, 90]
    longitude: float | None = None           # degrees, east positive, in [-180, 180]
    time: datetime | None = None             # aware: local civil time with its UTC offset
    sun_direction: np.ndarray | None = None  # unit, towards the sun (z > 0)
    turbidity: float = 3.0                   # in [1, 10]
    ground_albedo: float = 0.2               # in [0, 1]
    north: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0, 0.0]))   # unit, z = 0
    sun_scale: float = 1.0
    sun_scale_unknown: bool = False
    sky_scale: float = 1.0
    sky_scale_unknown: bool = False


@dataclass(frozen=True)
class EmitterSpec:
    """One checked emitter of scene.yaml; the loader reads its envmap and meshes later."""

    type: str
    radiance: np.ndarray | None = None       # constant, area: (C,)
    direction: np.ndarray | None = None      # directional: unit, the direction the light travels
    irradiance: np.ndarray | None = None     # directional: (C,)
    file: str | None = None                  # envmap, as written
    scale: float = 1.0                       # every type but sunsky (1.0 when unknown)
    meshes: tuple[str, ...] = ()             # area, as written
    scale_unknown: bool = False              # ``scale: unknown``
    sunsky: SunskySpec | None = None         # sunsky


@dataclass(frozen=True)
class SceneSpec:
    """The checked content of scene.yaml."""

    path: Path                               # the scene.yaml read
    name: str | None
    channels: tuple[str, ...]
    segments: tuple[Segment, ...]
    emitters: tuple[EmitterSpec, ...]
    photometry: Photometry = field(default_factory=Photometry)
    origin: tuple[float, float, float] | None = None   # where the local frame's (0, 0, 0) lies in the survey's


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
    origin = _origin(desc["origin"], f"{path}: origin") if "origin" in desc else None
    return SceneSpec(path, name, channels, segments, emitters, photometry, origin)


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
    known = _known(s["known"], kernels, reference, channels, f"{where} known") if "known" in s else None
    return Segment(name, meshes, kernels, reference, known)


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


def _known(value: object, kernels: tuple[str, ...], reference: dict[str, np.ndarray] | None, channels,
           where: str) -> dict[str, np.ndarray]:
    """``known: {kernel: value}``: weights held fixed (a calibration panel), each a kernel of the
    segment, in [0, 1], equal to the reference where both give it, and with the references of the
    other kernels summing to at most 1 per channel."""
    example = f"{{{kernels[0]}: 0.5}}"
    if not isinstance(value, dict) or not value:
        got = "an empty mapping" if isinstance(value, dict) else _shown(value)
        raise SceneError(f"{where} must map some of the segment's kernels {list(kernels)} to the weights "
                         f"held fixed, e.g. {example}; got {got}")
    value = {_canonical_or_same(k): v for k, v in value.items()}
    for k in value:
        if k not in kernels:
            raise SceneError(f"{where}: '{k}' is not a kernel of the segment (its kernels: {list(kernels)}); "
                             f"add it to the segment's kernels, or hold one of those, e.g. {example}")
    known = {k: _spectrum(v, channels, f"{where} {k}", unit=True) for k, v in value.items()}
    for k, v in known.items():
        if reference is not None and k in reference and not np.allclose(reference[k], v, rtol=0, atol=SUM_TOLERANCE):
            raise SceneError(f"{where} {k} = {_values(v)} differs from the segment's reference {k} = "
                             f"{_values(reference[k])}; a known weight is its reference: give one value")
    total = sum(known.values(), np.zeros(len(channels)))
    others = [k for k in (reference or {}) if k not in known]
    total = total + sum((reference[k] for k in others), np.zeros(len(channels)))
    c = int(np.argmax(total))
    if total[c] > 1 + SUM_TOLERANCE:
        terms = " + ".join(list(known) + [f"reference {k}" for k in others])
        raise SceneError(f"{where}: {terms} = {total[c]:.6g} > 1 in channel {channels[c]}; a segment's "
                         "weights sum to at most 1 per channel (energy conservation): lower them")
    return known


def _values(v: np.ndarray) -> str:
    """A (C,) value for a message: one number when every channel has it."""
    return f"{v[0]:g}" if np.all(v == v[0]) else "[" + ", ".join(f"{x:g}" for x in v) + "]"


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

    if t == "sunsky":
        return EmitterSpec(t, sunsky=_sunsky(e, where))
    scale, unknown = _scale(e.get("scale", 1.0), f"{where} scale")
    if t == "constant":
        return EmitterSpec(t, radiance=spectrum("radiance"), scale=scale, scale_unknown=unknown)
    if t == "directional":
        return EmitterSpec(t, direction=_direction(e["direction"], f"{where} direction"),
                           irradiance=spectrum("irradiance"), scale=scale, scale_unknown=unknown)
    if t == "envmap":
        return EmitterSpec(t, file=_text(e["file"], f"{where} file"), scale=scale, scale_unknown=unknown)
    return EmitterSpec(t, meshes=_names(e["meshes"], f"{where} meshes", "meshes/light.ply",
                                        empty=f"{where} meshes is empty; list the PLY files that emit"),
                       radiance=spectrum("radiance"), scale=scale, scale_unknown=unknown)


def _scale(value: object, where: str) -> tuple[float, bool]:
    """An emitter's ``scale`` (or a sunsky's ``sun_scale``/``sky_scale``): (number, False), or
    (1.0, True) for the word ``unknown``."""
    if value == UNKNOWN:
        return 1.0, True
    if isinstance(value, str):
        try:
            float(value)
        except ValueError:
            close = difflib.get_close_matches(value, [UNKNOWN], n=1, cutoff=0.6)
            hint = f" (did you mean '{UNKNOWN}'?)" if close else ""
            raise SceneError(f"{where} {_quoted(value)} is neither a number nor the word {UNKNOWN}{hint}; "
                             f"give a number >= 0 (it multiplies the light), or {UNKNOWN} to estimate it") from None
    scale = _number(value, where, f"a number >= 0 or the word {UNKNOWN}")
    if not np.isfinite(scale) or scale < 0:
        raise SceneError(f"{where} = {scale:g} must be finite and >= 0 (it multiplies the light), "
                         f"or the word {UNKNOWN}")
    return scale, False


def _sunsky(e: dict, where: str) -> SunskySpec:
    """A ``sunsky`` emitter: place and time, or ``sun_direction``; the atmosphere and the scales."""
    place = [k for k in PLACE_AND_TIME if k in e]
    if place and "sun_direction" in e:
        raise SceneError(f"{where} gives both {', '.join(place)} and sun_direction; give either latitude, "
                         "longitude and time (where and when), or sun_direction, not both")
    if not place and "sun_direction" not in e:
        raise SceneError(f"{where} needs latitude, longitude and time (where and when: the loader places "
                         "the sun), or sun_direction: add them")
    options: dict = {}
    if place:
        missing = [k for k in PLACE_AND_TIME if k not in e]
        if missing:
            raise SceneError(f"{where} misses {' and '.join(missing)}; give latitude, longitude and time "
                             "together (or sun_direction instead)")
        options["latitude"] = _in_range(e["latitude"], -90, 90, f"{where} latitude",
                                        "degrees, north positive")
        options["longitude"] = _in_range(e["longitude"], -180, 180, f"{where} longitude",
                                         "degrees, east positive")
        options["time"] = _time(e["time"], f"{where} time")
        if "north" in e:
            options["north"] = _north(e["north"], f"{where} north")
    else:
        options["sun_direction"] = _sun_direction(e["sun_direction"], f"{where} sun_direction")
        if "north" in e:
            raise SceneError(f"{where}: north serves only to place the sun from latitude, longitude and "
                             "time; with sun_direction (a world direction already) remove it")
    if "turbidity" in e:
        options["turbidity"] = _in_range(e["turbidity"], 1, 10, f"{where} turbidity",
                                         "Hosek-Wilkie's range; about 2 for a clear arctic sky, 3 temperate, "
                                         "6-10 hazy")
    if "ground_albedo" in e:
        options["ground_albedo"] = _in_range(e["ground_albedo"], 0, 1, f"{where} ground_albedo",
                                             "a reflectance")
    for part in ("sun", "sky"):
        if f"{part}_scale" in e:
            options[f"{part}_scale"], options[f"{part}_scale_unknown"] = _scale(e[f"{part}_scale"],
                                                                                f"{where} {part}_scale")
    return SunskySpec(**options)


def _in_range(value: object, low: float, high: float, where: str, what: str) -> float:
    x = _number(value, where, f"a number in [{low:g}, {high:g}] ({what})")
    if not low <= x <= high:
        raise SceneError(f"{where} = {x:g} is outside [{low:g}, {high:g}] ({what}); fix it")
    return x


def _time(value: object, where: str) -> datetime:
    """An ISO 8601 date and time with its UTC offset (YAML may have read it as a datetime already)."""
    example = "2026-06-21T14:00:00+02:00 (local time and its offset from UTC; Z for UTC)"
    text = value.isoformat() if isinstance(value, (date, datetime)) else value
    if isinstance(value, date) and not isinstance(value, datetime):
        raise SceneError(f"{where} {text} is a date without a time of day; write e.g. {example}")
    if isinstance(value, datetime):
        t = value
    elif isinstance(value, str):
        try:
            date.fromisoformat(value.strip())
        except ValueError:
            pass
        else:
            raise SceneError(f"{where} '{value}' is a date without a time of day; write e.g. {example}")
        try:
            t = datetime.fromisoformat(value.strip())
        except ValueError:
            raise SceneError(f"{where} '{one_line(value, 60)}' is not an ISO 8601 date and time; write "
                             f"e.g. {example}") from None
    else:
        raise SceneError(f"{where} must be an ISO 8601 date and time, e.g. {example}; got {_shown(value)}")
    if t.utcoffset() is None:
        raise SceneError(f"{where} '{text}' has no UTC offset, so the sun's place is ambiguous; append the "
                         "offset of the clock it was read on, e.g. +02:00 for CEST, -05:00 for EST, Z for UTC")
    return t


def _north(value: object, where: str) -> np.ndarray:
    """The world direction of geographic north: horizontal (within a few degrees), normalised."""
    what = "3 finite numbers, not all 0, horizontal (z about 0): the world direction of geographic north"
    n = np.array([_number(x, where, what) for x in _list(value, where, "0, 1, 0")])
    if n.shape != (3,) or not np.isfinite(n).all() or np.linalg.norm(n) == 0:
        raise SceneError(f"{where} must be {what}; got {_shown(value)}")
    tilt = np.degrees(np.arcsin(abs(n[2]) / np.linalg.norm(n)))
    if tilt > NORTH_TILT_MAX_DEG:
        raise SceneError(f"{where} = {_shown(value)} points {tilt:.1f} deg out of the horizontal plane "
                         f"(at most {NORTH_TILT_MAX_DEG:g}); north is horizontal: give it z = 0")
    n[2] = 0.0
    return n / np.linalg.norm(n)


def _sun_direction(value: object, where: str) -> np.ndarray:
    what = "3 finite numbers, not all 0: the direction towards the sun, z > 0"
    d = np.array([_number(x, where, what) for x in _list(value, where, "0.3, -0.4, 0.87")])
    if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) == 0:
        raise SceneError(f"{where} must be {what}; got {_shown(value)}")
    if d[2] <= 0:
        raise SceneError(f"{where} = {_shown(value)} points at or below the horizon; it points towards the sun "
                         "(z > 0), the opposite of a directional emitter's direction")
    return d / np.linalg.norm(d)


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
    vignetting, profile = _vignetting(p["vignetting"], f"{where} vignetting") if "vignetting" in p else ("none", None)
    return Photometry(encoding=encoding, exposure=exposure, reference_view=reference, saturation=saturation,
                      vignetting=vignetting, vignetting_profile=profile)


def _vignetting(value: object, where: str) -> tuple[str, tuple[float, float, float] | None]:
    """``none`` | ``estimate`` | ``[a1, a2, a3]``: pixel = (1 + a1 r² + a2 r⁴ + a3 r⁶) · radiance."""
    choices = ", ".join(f"{k} ({v})" for k, v in VIGNETTING.items())
    if isinstance(value, str) and value in ("none", "estimate"):
        return value, None
    if not isinstance(value, list):
        raise SceneError(f"{where} {_quoted(value)} unknown; use {choices}")
    if len(value) != 3:
        raise SceneError(f"{where} has {len(value)} coefficient(s); give 3, [a1, a2, a3] with pixel = "
                         "(1 + a1 r^2 + a2 r^4 + a3 r^6) · radiance (r: distance from the principal point / "
                         "half the image diagonal)")
    a = np.array([_number(x, where, "[a1, a2, a3], 3 finite numbers") for x in value])
    if not np.isfinite(a).all():
        raise SceneError(f"{where} = {a.tolist()} must be finite")
    r2 = np.linspace(0.0, 1.0, 1001)
    falloff = 1 + a[0] * r2 + a[1] * r2 ** 2 + a[2] * r2 ** 3
    if falloff.min() <= 0:
        r = np.sqrt(r2[np.argmin(falloff)])
        raise SceneError(f"{where} = {a.tolist()} makes 1 + a1 r^2 + a2 r^4 + a3 r^6 = {falloff.min():.3g} <= 0 "
                         f"at r = {r:.2f} (r = 1 at the image corners); the lens passes some light everywhere: "
                         "check the signs")
    return "known", tuple(float(x) for x in a)


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


def _origin(value: object, where: str) -> tuple[float, float, float]:
    """``origin: [x, y, z]``: 3 finite numbers, the survey coordinates of the local (0, 0, 0)."""
    what = "3 finite numbers [x, y, z] (the survey coordinates of the scene's 0, 0, 0)"
    o = np.array([_number(x, where, what) for x in _list(value, where, "652340.0, 6862275.0, 35.0")])
    if o.shape != (3,) or not np.isfinite(o).all():
        raise SceneError(f"{where} must be {what}; got {_shown(value)}")
    return tuple(float(x) for x in o)


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
    text = " ".join(repr(value).split())       # not one_line: it would drop a list's "[...]" as a C++ location
    return text if len(text) <= 60 else text[:57] + "..."
