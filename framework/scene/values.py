"""Readers of scene.yaml's values, shared by :mod:`framework.scene.schema` and
:mod:`framework.scene.emitter_schema`: each checks one value and raises
:class:`~framework.errors.SceneError` with one line naming the file, the key and the fix."""
from __future__ import annotations

import difflib

import numpy as np

from framework.errors import SceneError
from framework.scene.model import CHANNELS


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


def read_mapping(value: object, keys: dict[str, bool], where: str) -> dict:
    """``value`` as a mapping with only ``keys`` and every required one; ``where`` begins the
    messages (``.../scene.yaml`` or ``.../scene.yaml: segment 'wall'``)."""
    allowed = ", ".join(keys)
    if not isinstance(value, dict):
        raise SceneError(f"{where} must be a mapping with keys {allowed}; got {shown(value)}")
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


def read_list(value: object, where: str, example: str) -> list:
    if not isinstance(value, list):
        raise SceneError(f"{where} must be a list, e.g. [{example}]; got {shown(value)}")
    return value


def read_names(value: object, where: str, example: str, *, empty: str) -> tuple[str, ...]:
    """A non-empty list of non-empty strings (mesh paths, kernel names)."""
    items = read_list(value, where, value if isinstance(value, str) and value else example)
    if not items:
        raise SceneError(empty)
    return tuple(read_text(v, f"{where} item {j}") for j, v in enumerate(items))


def read_text(value: object, where: str) -> str:
    if isinstance(value, str) and value and not value.strip():
        raise SceneError(f"{where} must be a non-empty string; got a blank string ({len(value)} "
                         f"whitespace character{'s' if len(value) > 1 else ''}, {value!r}): give it a name")
    if not isinstance(value, str) or not value.strip():
        raise SceneError(f"{where} must be a non-empty string; got {shown(value)} (quote it if it "
                         "looks like a number)")
    return value


def read_channels(value: object, where: str) -> tuple[str, ...]:
    if value not in CHANNELS:
        raise SceneError(f"{where} '{value}' unknown; use rgb or mono")
    return CHANNELS[value]


def read_number(value: object, where: str, what: str) -> float:
    """A float; a string that reads as one is accepted because YAML 1.1 (PyYAML) reads ``1e3``,
    without a dot, as a string."""
    problem = SceneError(f"{where} must be {what}; got {shown(value)}")
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise problem
    try:
        return float(value)
    except ValueError:
        raise problem from None


def read_in_range(value: object, low: float, high: float, where: str, what: str) -> float:
    x = read_number(value, where, f"a number in [{low:g}, {high:g}] ({what})")
    if not low <= x <= high:
        raise SceneError(f"{where} = {x:g} is outside [{low:g}, {high:g}] ({what}); fix it")
    return x


def read_spectrum(value: object, channels: tuple[str, ...], where: str, *, unit: bool) -> np.ndarray:
    """One number or one per channel, as a (C,) array: a reflectance in [0, 1] (``unit``) or a
    radiance / irradiance >= 0."""
    what = f"a number or a list of {len(channels)} numbers"
    v = np.array([read_number(x, where, what) for x in (value if isinstance(value, list) else [value])])
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


def read_vector(value: object, where: str, what: str, example: str) -> np.ndarray:
    """3 finite numbers, not all 0 (``what`` says what they are, ``example`` shows some)."""
    d = np.array([read_number(x, where, what) for x in read_list(value, where, example)])
    if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) == 0:
        raise SceneError(f"{where} must be {what}; got {shown(value)}")
    return d


def read_direction(value: object, where: str) -> np.ndarray:
    """The unit direction light travels."""
    d = read_vector(value, where, "3 finite numbers, not all 0 (the direction the light travels)", "0.4, 0.3, -0.87")
    return d / np.linalg.norm(d)


def quoted(value: object) -> str:
    """A value that should have been one of some names, for a message: 'gamma', or as shown."""
    return f"'{one_line(value, 60)}'" if isinstance(value, str) else shown(value)


def shown(value: object) -> str:
    """A short, one-line rendering of a YAML value for a message."""
    if value is None:
        return "nothing (null)"
    if isinstance(value, str):
        return f"the string '{one_line(value, 60)}'"
    if isinstance(value, dict):
        return "a mapping"
    text = " ".join(repr(value).split())       # not one_line: it would drop a list's "[...]" as a C++ location
    return text if len(text) <= 60 else text[:57] + "..."
