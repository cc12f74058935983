"""The schema of ``scene.yaml`` (``docs/scene-format.md``): a small typed reader written by hand.

:func:`read_scene_yaml` checks the whole file (YAML syntax, keys given twice, unknown keys,
types, ranges, unique segment names, Σ_kernels ρ ≤ 1) before the loader opens any mesh, image
or COLMAP file, and returns a :class:`SceneSpec` of checked values. Every problem raises
:class:`~framework.errors.SceneError` with one line naming the file, the key and the fix.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from framework import brdf_kernels as kernel_registry
from framework.errors import SceneError
from framework.scene.emitter_schema import EmitterSpec, read_emitter
from framework.scene.model import Photometry, Segment
from framework.scene.values import (one_line, quoted, read_channels, read_list, read_mapping, read_names,
                                    read_number, read_spectrum, read_text, shown)

# The keys of each mapping, in the order the docs list them: True for a required key.
TOP_KEYS = {"name": False, "channels": False, "origin": False, "segments": True, "emitters": True,
            "lights": False, "photometry": False}
LIGHT_KEYS = {"name": True, "views": True, "emitters": True}
#: emitter types a light of ``lights`` may hold: an ``area`` emitter's meshes are geometry, the
#: same under every light
LIGHT_TYPES = ("constant", "directional", "envmap", "sunsky")
SEGMENT_KEYS = {"name": True, "meshes": True, "kernels": False, "reference": False, "known": False}
PHOTOMETRY_KEYS = {"encoding": False, "exposure": False, "reference_view": False, "saturation": False,
                   "vignetting": False, "resampling": False}
VIGNETTING = {"none": "no lens falloff", "estimate": "one unknown profile per camera",
              "[a1, a2, a3]": "a known profile"}
ENCODINGS = {"linear": "pixel values are radiance", "srgb": "8/16-bit camera output, decoded to linear"}
EXPOSURES = {"known": "pixel = radiance", "per_view": "one unknown gain per view and channel"}
RESAMPLINGS = {"bilinear": "2 x 2 pixels", "cubic": "Keys' cubic convolution, 4 x 4 pixels, less blur"}
DEFAULT_KERNELS = ("diffuse",)
# Σ ρ ≤ 1 up to the rounding of the 7 decimals scene.yaml is written with
SUM_TOLERANCE = 1e-9


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
    lights: tuple[LightSpec, ...] = ()       # ``lights``: the views photographed under other emitters


@dataclass(frozen=True)
class LightSpec:
    """One checked entry of ``lights``: the views photographed under ``emitters``."""

    name: str
    views: tuple[str, ...]
    emitters: tuple[EmitterSpec, ...]


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
    desc = read_mapping(_load_yaml(root), TOP_KEYS, str(path))
    channels = read_channels(desc.get("channels", "rgb"), f"{path}: channels")
    segments = tuple(_segment(s, i, path, channels) for i, s in enumerate(
        read_list(desc["segments"], f"{path}: segments", "{name: ground, meshes: [meshes/ground.ply]}")))
    if not segments:
        raise SceneError(f"{path}: 'segments' is empty; list at least one segment")
    _unique_names(segments, path)
    emitters = tuple(read_emitter(e, i, path, channels) for i, e in enumerate(
        read_list(desc["emitters"], f"{path}: emitters", "{type: constant, radiance: 1.0}")))
    if not emitters:
        raise SceneError(f"{path}: no emitters; the illumination must be known: list at least one")
    name = read_text(desc["name"], f"{path}: name") if "name" in desc else None
    photometry = _photometry(desc["photometry"], f"{path}: photometry") if "photometry" in desc else Photometry()
    origin = _origin(desc["origin"], f"{path}: origin") if "origin" in desc else None
    lights = _lights(desc["lights"], path, channels) if "lights" in desc else ()
    return SceneSpec(path, name, channels, segments, emitters, photometry, origin, lights)


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
    s = read_mapping(s, SEGMENT_KEYS, where)
    name = read_text(s["name"], f"{where} name")
    meshes = read_names(s["meshes"], f"{where} meshes", "meshes/ground.ply",
                    empty=f"{where} has no meshes; list its PLY files")
    kernels = _kernels(s["kernels"], f"{where} kernels") if "kernels" in s else DEFAULT_KERNELS
    reference = _reference(s["reference"], kernels, channels, f"{where} reference") if "reference" in s else None
    known = _known(s["known"], kernels, reference, channels, f"{where} known") if "known" in s else None
    return Segment(name, meshes, kernels, reference, known)


def _lights(value: object, path: Path, channels: tuple[str, ...]) -> tuple[LightSpec, ...]:
    """``lights``: a non-empty list of ``{name, views, emitters}``, the names unique, each view in
    one light at most, the emitters read as ``emitters`` is (``area`` refused)."""
    example = "{name: morning, views: [morning_000.png], emitters: [{type: constant, radiance: 0.5}]}"
    items = read_list(value, f"{path}: lights", example)
    if not items:
        raise SceneError(f"{path}: lights is empty; list the views photographed under other emitters, "
                         f"e.g. [{example}], or leave the key out (every view is lit by emitters)")
    out: list[LightSpec] = []
    for i, x in enumerate(items):
        named = isinstance(x, dict) and isinstance(x.get("name"), str) and x["name"].strip()
        where = f"{path}: light '{x['name']}'" if named else f"{path}: light {i}"
        x = read_mapping(x, LIGHT_KEYS, where)
        name = read_text(x["name"], f"{where} name")
        if any(o.name == name for o in out):
            raise SceneError(f"{path}: lights {[o.name for o in out].index(name)} and {i} are both named "
                             f"'{name}'; give each light its own name (it names the views' light in the results)")
        views = read_names(x["views"], f"{where} views", "morning_000.png",
                           empty=f"{where} views is empty; list the images (names of images.txt) photographed "
                                 "under this light")
        for v in views:
            other = next((o.name for o in out if v in o.views), None)
            if other is not None or views.count(v) > 1:
                again = f"lights '{other}' and '{name}'" if other is not None else f"light '{name}' twice"
                raise SceneError(f"{where} views: {v} is in {again}; a photograph was taken under one light: "
                                 "list it once")
        emitters = tuple(read_emitter(e, j, path, channels, within=f"light '{name}' ") for j, e in enumerate(
            read_list(x["emitters"], f"{where} emitters", "{type: constant, radiance: 1.0}")))
        if not emitters:
            raise SceneError(f"{where} emitters is empty; list the emitters of this light (at least one)")
        for j, e in enumerate(emitters):
            if e.type not in LIGHT_TYPES:
                raise SceneError(f"{where} emitter {j} ({e.type}): an area emitter's meshes are geometry, the "
                                 f"same under every light, so a light takes only {', '.join(LIGHT_TYPES)}; "
                                 "list area emitters under emitters")
        out.append(LightSpec(name, views, emitters))
    return tuple(out)


def _kernels(value: object, where: str) -> tuple[str, ...]:
    ks = read_names(value, where, "diffuse", empty=f"{where} is empty; list at least one kernel, e.g. "
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
                         f"e.g. {{{kernels[0]}: 0.5}}; got {shown(value)}")
    value = {_canonical_or_same(k): v for k, v in value.items()}
    ref = {k: read_spectrum(v, channels, f"{where} {k}", unit=True)
           for k, v in read_mapping(value, dict.fromkeys(kernels, False), where).items()}
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
        got = "an empty mapping" if isinstance(value, dict) else shown(value)
        raise SceneError(f"{where} must map some of the segment's kernels {list(kernels)} to the weights "
                         f"held fixed, e.g. {example}; got {got}")
    value = {_canonical_or_same(k): v for k, v in value.items()}
    for k in value:
        if k not in kernels:
            raise SceneError(f"{where}: '{k}' is not a kernel of the segment (its kernels: {list(kernels)}); "
                             f"add it to the segment's kernels, or hold one of those, e.g. {example}")
    known = {k: read_spectrum(v, channels, f"{where} {k}", unit=True) for k, v in value.items()}
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


def _photometry(value: object, where: str) -> Photometry:
    """The ``photometry`` mapping: how the photographs encode radiance."""
    p = read_mapping(value, PHOTOMETRY_KEYS, where)
    encoding = p.get("encoding")
    if "encoding" in p and encoding not in ENCODINGS:
        raise SceneError(f"{where} encoding {quoted(encoding)} unknown; use "
                         + " or ".join(f"{k} ({v})" for k, v in ENCODINGS.items()))
    exposure = p.get("exposure", "known")
    if exposure not in EXPOSURES:
        raise SceneError(f"{where} exposure {quoted(exposure)} unknown; use "
                         + " or ".join(f"{k} ({v})" for k, v in EXPOSURES.items()))
    reference = read_text(p["reference_view"], f"{where} reference_view") if "reference_view" in p else None
    if exposure == "per_view" and reference is None:
        raise SceneError(f"{where} exposure per_view needs reference_view: add reference_view: <an image "
                         "name of images.txt>, the view whose gains are 1 (they fix the scale)")
    if exposure == "known" and reference is not None:
        raise SceneError(f"{where} reference_view is used only with exposure: per_view; add exposure: "
                         "per_view, or remove reference_view")
    saturation = None
    if "saturation" in p:
        saturation = read_number(p["saturation"], f"{where} saturation", "a number in (0, 1]")
        if not 0 < saturation <= 1:
            raise SceneError(f"{where} saturation = {saturation:g} must lie in (0, 1] (a fraction of the "
                             "largest encoded value, e.g. 0.99; 1 ignores only pixels at the maximum)")
    vignetting, profile = _vignetting(p["vignetting"], f"{where} vignetting") if "vignetting" in p else ("none", None)
    resampling = p.get("resampling", Photometry.resampling)
    if resampling not in RESAMPLINGS:
        raise SceneError(f"{where} resampling {quoted(resampling)} unknown; use "
                         + " or ".join(f"{k} ({v})" for k, v in RESAMPLINGS.items()))
    return Photometry(encoding=encoding, exposure=exposure, reference_view=reference, saturation=saturation,
                      vignetting=vignetting, vignetting_profile=profile, resampling=resampling)


def _vignetting(value: object, where: str) -> tuple[str, tuple[float, float, float] | None]:
    """``none`` | ``estimate`` | ``[a1, a2, a3]``: pixel = (1 + a1 r² + a2 r⁴ + a3 r⁶) · radiance."""
    choices = ", ".join(f"{k} ({v})" for k, v in VIGNETTING.items())
    if isinstance(value, str) and value in ("none", "estimate"):
        return value, None
    if not isinstance(value, list):
        raise SceneError(f"{where} {quoted(value)} unknown; use {choices}")
    if len(value) != 3:
        raise SceneError(f"{where} has {len(value)} coefficient(s); give 3, [a1, a2, a3] with pixel = "
                         "(1 + a1 r^2 + a2 r^4 + a3 r^6) · radiance (r: distance from the principal point / "
                         "half the image diagonal)")
    a = np.array([read_number(x, where, "[a1, a2, a3], 3 finite numbers") for x in value])
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


def _origin(value: object, where: str) -> tuple[float, float, float]:
    """``origin: [x, y, z]``: 3 finite numbers, the survey coordinates of the local (0, 0, 0)."""
    what = "3 finite numbers [x, y, z] (the survey coordinates of the scene's 0, 0, 0)"
    o = np.array([read_number(x, where, what) for x in read_list(value, where, "652340.0, 6862275.0, 35.0")])
    if o.shape != (3,) or not np.isfinite(o).all():
        raise SceneError(f"{where} must be {what}; got {shown(value)}")
    return tuple(float(x) for x in o)


