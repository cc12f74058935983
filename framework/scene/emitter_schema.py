"""The ``emitters`` of scene.yaml: each type's keys, scales (a number, or ``unknown``) and the
``sunsky`` emitter by place and time or sun direction (docs/scene-format.md)."""
from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from datetime import date, datetime
from pathlib import Path

import numpy as np

from framework.errors import SceneError
from framework.scene.values import (one_line, quoted, read_direction, read_in_range, read_mapping,
                                    read_names, read_number, read_spectrum, read_text, read_vector, shown)


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


def read_emitter(e: object, i: int, path: Path, channels: tuple[str, ...], *, within: str = "") -> EmitterSpec:
    """Emitter ``i`` of scene.yaml ``path``'s ``emitters`` (or of a light's: ``within`` is then
    ``"light 'name' "``, which the messages name)."""
    where = f"{path}: {within}emitter {i}"
    if not isinstance(e, dict):
        raise SceneError(f"{where} must be a mapping with a type, e.g. {{type: constant, radiance: 1.0}}; "
                         f"got {shown(e)}")
    t = e.get("type")
    if t not in EMITTER_TYPES:
        problem = f"type '{t}' unknown" if "type" in e else "has no type"
        raise SceneError(f"{where} {problem}; use one of {', '.join(EMITTER_TYPES)}")
    where = f"{where} ({t})"
    e = read_mapping(e, EMITTER_KEYS[t], where)

    def spectrum(key: str) -> np.ndarray:
        return read_spectrum(e[key], channels, f"{where} {key}", unit=False)

    if t == "sunsky":
        return EmitterSpec(t, sunsky=_sunsky(e, where))
    scale, unknown = _scale(e.get("scale", 1.0), f"{where} scale")
    if t == "constant":
        return EmitterSpec(t, radiance=spectrum("radiance"), scale=scale, scale_unknown=unknown)
    if t == "directional":
        return EmitterSpec(t, direction=read_direction(e["direction"], f"{where} direction"),
                           irradiance=spectrum("irradiance"), scale=scale, scale_unknown=unknown)
    if t == "envmap":
        return EmitterSpec(t, file=read_text(e["file"], f"{where} file"), scale=scale, scale_unknown=unknown)
    return EmitterSpec(t, meshes=read_names(e["meshes"], f"{where} meshes", "meshes/light.ply",
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
            raise SceneError(f"{where} {quoted(value)} is neither a number nor the word {UNKNOWN}{hint}; "
                             f"give a number >= 0 (it multiplies the light), or {UNKNOWN} to estimate it") from None
    scale = read_number(value, where, f"a number >= 0 or the word {UNKNOWN}")
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
        options["latitude"] = read_in_range(e["latitude"], -90, 90, f"{where} latitude",
                                        "degrees, north positive")
        options["longitude"] = read_in_range(e["longitude"], -180, 180, f"{where} longitude",
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
        options["turbidity"] = read_in_range(e["turbidity"], 1, 10, f"{where} turbidity",
                                         "Hosek-Wilkie's range; about 2 for a clear arctic sky, 3 temperate, "
                                         "6-10 hazy")
    if "ground_albedo" in e:
        options["ground_albedo"] = read_in_range(e["ground_albedo"], 0, 1, f"{where} ground_albedo",
                                             "a reflectance")
    for part in ("sun", "sky"):
        if f"{part}_scale" in e:
            options[f"{part}_scale"], options[f"{part}_scale_unknown"] = _scale(e[f"{part}_scale"],
                                                                                f"{where} {part}_scale")
    return SunskySpec(**options)


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
        raise SceneError(f"{where} must be an ISO 8601 date and time, e.g. {example}; got {shown(value)}")
    if t.utcoffset() is None:
        raise SceneError(f"{where} '{text}' has no UTC offset, so the sun's place is ambiguous; append the "
                         "offset of the clock it was read on, e.g. +02:00 for CEST, -05:00 for EST, Z for UTC")
    return t


def _north(value: object, where: str) -> np.ndarray:
    """The world direction of geographic north: horizontal (within a few degrees), normalised."""
    what = "3 finite numbers, not all 0, horizontal (z about 0): the world direction of geographic north"
    n = read_vector(value, where, what, "0, 1, 0")
    tilt = np.degrees(np.arcsin(abs(n[2]) / np.linalg.norm(n)))
    if tilt > NORTH_TILT_MAX_DEG:
        raise SceneError(f"{where} = {shown(value)} points {tilt:.1f} deg out of the horizontal plane "
                         f"(at most {NORTH_TILT_MAX_DEG:g}); north is horizontal: give it z = 0")
    n[2] = 0.0
    return n / np.linalg.norm(n)


def _sun_direction(value: object, where: str) -> np.ndarray:
    d = read_vector(value, where, "3 finite numbers, not all 0: the direction towards the sun, z > 0", "0.3, -0.4, 0.87")
    if d[2] <= 0:
        raise SceneError(f"{where} = {shown(value)} points at or below the horizon; it points towards the sun "
                         "(z > 0), the opposite of a directional emitter's direction")
    return d / np.linalg.norm(d)
