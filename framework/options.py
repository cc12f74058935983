"""Typed method options: one frozen dataclass per method, built once from the composed config.

A method declares its options as a frozen dataclass whose fields are made by :func:`option`:
the field's ``doc`` is the one description of the option (``docs/cli.md``'s tables are generated
from it, :func:`option_rows`), its ``check`` validates and converts the value, its ``default`` is
the option's one default. A method's YAML (``framework/conf/method/<name>.yaml``) is generated
from the fields (:func:`defaults_of`, ``python -m framework.method_yaml``; the test suite checks it
is current), so Hydra composes the defaults and the presets override them in their own YAML; no
code repeats a default. A nested dataclass is a nested mapping (``method.solver.*``).

:func:`build` turns the method's config group into the dataclass: every key checked in field
order, an unknown key refused with the list of options, the first bad value refused with one
line naming it (``method.refine=9 is out of range: use an integer in [0, 8]``); an infinite or NaN
number is refused in every option, whatever its check.

The checks are small callables with an ``allowed`` text (the docs' "allowed values" column):
:func:`choice`, :func:`number`, :func:`flag`, :func:`either`, :func:`nullable` and :data:`ANY`.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf

from framework.errors import ConfigError

#: keys of a method's config group that the framework reads itself: ``name`` (the registry key)
#: and ``tail_bounces`` (what ``render.tail_bounces=auto`` resolves to, :mod:`framework.config`)
FRAMEWORK_KEYS = ("name", "tail_bounces")


class Check:
    """A value check: ``check(key, value)`` returns the converted value or raises ConfigError
    naming ``key``; ``allowed`` says what passes, for the docs."""

    def __init__(self, allowed: str, fn: Callable[[str, Any], Any]):
        self.allowed, self._fn = allowed, fn

    def __call__(self, key: str, value):
        return self._fn(key, value)


def _plain(value):
    """OmegaConf containers as Python ones (lists as tuples, mappings as dicts)."""
    if isinstance(value, (DictConfig, ListConfig)):
        value = OmegaConf.to_container(value, resolve=True)
    if isinstance(value, list):
        return tuple(_plain(v) for v in value)
    return value


def choice(*choices) -> Check:
    """One of ``choices`` (compared as text, so ``true`` matches ``True``); returns the choice."""
    texts = [str(c) for c in choices]

    def check(key, value):
        if str(value) not in texts:
            raise ConfigError(f"{key}={value} is not allowed: use one of {', '.join(texts)}")
        return choices[texts.index(str(value))]
    return Check(", ".join(f"`{c}`" for c in texts), check)


def flag() -> Check:
    """``true`` or ``false``; returns a bool."""
    inner = choice(True, False)
    return Check("`true`, `false`", inner)


def _interval(lo, hi, lo_open: bool) -> str:
    """The docs' form of a range: ``≥ 0``, ``> 0``, ``in [0, 8]``, ``in (0, 0.5]``."""
    if hi is None:
        return f"{'>' if lo_open else '≥'} {lo:g}"
    return f"in {'(' if lo_open else '['}{lo:g}, {hi:g}]"


def number(lo: float, hi: float | None = None, *, integer: bool = False, lo_open: bool = False) -> Check:
    """A number (an integer with ``integer``) in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``)."""
    what = "an integer" if integer else "a number"

    def check(key, value):
        kinds = (int,) if integer else (int, float)
        ok = isinstance(value, kinds) and not isinstance(value, bool)
        ok = ok and (value > lo if lo_open else value >= lo) and (hi is None or value <= hi)
        if not ok:
            rng = f"{'(' if lo_open else '['}{lo}, {hi if hi is not None else '∞'}{']' if hi is not None else ')'}"
            raise ConfigError(f"{key}={value} is out of range: use {what} in {rng}")
        return int(value) if integer else float(value)
    return Check(f"{'integer' if integer else 'number'} {_interval(lo, hi, lo_open)}", check)


def either(word: str, other: Check) -> Check:
    """The word ``word`` (returned as is) or what ``other`` accepts."""
    return Check(f"`{word}` or {other.allowed}", lambda key, value: word if str(value) == word else other(key, value))


def nullable(other: Check) -> Check:
    """``null`` (None) or what ``other`` accepts."""
    return Check(f"`null` or {other.allowed}", lambda key, value: None if value is None else other(key, value))


#: any value (checked where it is used, against the scene): lists become tuples
ANY = Check("see meaning", lambda key, value: _plain(value))


def option(doc: str, check: Check = ANY, *, default=dataclasses.MISSING, default_factory=dataclasses.MISSING):
    """A field of an options dataclass: its description, its check and its default, written as a
    user gives it (``"all"``, a list), which :func:`build` checks and converts like a given value;
    a nested options dataclass takes ``default_factory`` (its class)."""
    if default is dataclasses.MISSING and default_factory is dataclasses.MISSING:
        raise TypeError(f"option {doc[:40]!r}... has no default: give default= or default_factory=")
    return dataclasses.field(default=default, default_factory=default_factory,
                             metadata={"doc": " ".join(doc.split()), "check": check})


def defaults_of(cls) -> dict:
    """The defaults of the options dataclass ``cls`` as a nested mapping in field order, as a
    user writes them (lists for tuples): what the method's YAML holds."""
    out = {}
    for f in dataclasses.fields(cls):
        sub = _resolved(cls, f)
        if dataclasses.is_dataclass(sub):
            out[f.name] = defaults_of(sub)
        else:
            out[f.name] = list(f.default) if isinstance(f.default, tuple) else f.default
    return out


def build(cls, cfg: Mapping, *, section: str = "method", ignore: tuple[str, ...] = FRAMEWORK_KEYS,
          unknown_hint: Callable[[str], str] | None = None):
    """``cls`` from the config mapping ``cfg``, every field checked (module docstring); a key
    ``cfg`` lacks takes the field's default, so ``build(cls, {})`` is the defaults.

    Parameters
    ----------
    cls : type
        A frozen dataclass whose fields come from :func:`option` (or are dataclasses themselves).
    cfg : Mapping
        The method's config group (a ``DictConfig`` or a dict).
    section : str
        The keys' prefix in messages (``method``, ``method.solver``).
    ignore : tuple of str
        Keys of ``cfg`` that belong to the framework (:data:`FRAMEWORK_KEYS`) at the top level.
    unknown_hint : callable, optional
        ``unknown_hint(key)``: the message for an unknown key (which other methods have it); by
        default the list of this section's options.

    Raises
    ------
    ConfigError
        For an unknown key, or the first value its check refuses.
    """
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = [str(k) for k in cfg if k not in fields and k not in ignore]
    if unknown:
        key = f"{section}.{unknown[0]}"
        if unknown_hint is not None:
            raise ConfigError(unknown_hint(key))
        raise ConfigError(f"{key} is not an option of {section}: use one of "
                          f"{', '.join(fields)} (docs/cli.md lists them)")
    values = {}
    for name, f in fields.items():
        key = f"{section}.{name}"
        if dataclasses.is_dataclass(f.type) or dataclasses.is_dataclass(_resolved(cls, f)):
            sub = cfg.get(name, {})
            if not isinstance(sub, Mapping):
                raise ConfigError(f"{key}={sub} is not a mapping: give its keys as {key}.<key>=value")
            values[name] = build(_resolved(cls, f), sub, section=key, ignore=(), unknown_hint=unknown_hint)
        else:   # a key the config lacks takes the field's default, checked like a given value
            value = cfg[name] if name in cfg else f.default
            _refuse_non_finite(key, _plain(value))
            values[name] = f.metadata["check"](key, value)
    return cls(**values)


def _refuse_non_finite(key: str, value) -> None:
    """Raise ConfigError when ``value`` is or holds an infinite or NaN number: a run would compute
    with it and results.json, which holds only finite numbers, could not record the setting."""
    if _non_finite(value):
        raise ConfigError(f"{key}={value} is not finite (inf or nan): give finite numbers "
                          "(docs/cli.md lists the allowed values)")


def _non_finite(value) -> bool:
    if isinstance(value, dict):
        return any(_non_finite(v) for v in value.values())
    if isinstance(value, tuple):
        return any(_non_finite(v) for v in value)
    return isinstance(value, float) and not math.isfinite(value)


def _resolved(cls, f):
    """The field's type as a class (annotations are strings under ``from __future__ import annotations``)."""
    import typing
    return typing.get_type_hints(cls)[f.name] if isinstance(f.type, str) else f.type


def option_rows(cls, defaults: Mapping, *, section: str = "method") -> list[tuple[str, str, str, str]]:
    """``(override, allowed, default, meaning)`` per option of ``cls``, nested ones flattened, in
    field order: the rows of docs/cli.md's method tables (``defaults``: the YAML's values)."""
    rows = []
    for f in dataclasses.fields(cls):
        key, sub = f"{section}.{f.name}", _resolved(cls, f)
        if dataclasses.is_dataclass(sub):
            rows += option_rows(sub, defaults[f.name], section=key)
            continue
        rows.append((key, f.metadata["check"].allowed, _shown(defaults[f.name]), f.metadata["doc"]))
    return rows


def _shown(value) -> str:
    value = _plain(value)
    if value is None:
        return "`null`"
    if isinstance(value, bool):
        return f"`{str(value).lower()}`"
    if isinstance(value, tuple):
        return "`[" + ", ".join(map(str, value)) + "]`"
    if isinstance(value, dict):
        return "`{" + ", ".join(f"{k}: {v}" for k, v in value.items()) + "}`"
    if isinstance(value, str):
        return f"`{value}`"
    return f"{value:g}" if isinstance(value, float) else str(value)
