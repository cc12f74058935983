"""Python Mitsuba plugins written once, as module-level classes, and instantiated per variant.

A plugin must derive from the *current* variant's base class (``mi.BSDF``,
``mi.SamplingIntegrator``...), which differs between variants, and nanobind types accept a single
base: no ``class Plugin(Mixin, mi.BSDF)``. So the plugin's methods are written in a plain class
(the *mixin*) and copied onto a subclass of the variant's base, built and registered once per
variant, so that one process can run rgb and mono scenes. The mixin may itself derive from plain
classes (one job each); their attributes are copied too. The mixin's methods therefore cannot
use zero-argument ``super()``: they call the base through ``mi`` (the active variant).
"""
from __future__ import annotations

from collections.abc import Callable

import mitsuba as mi

_CLASSES: dict[tuple[str, str], type] = {}

# Attributes of a plain class that describe that class itself, not its behaviour.
_OWN = ("__dict__", "__weakref__", "__qualname__")


def plugin_class(name: str, mixin: type, base: type, register: Callable, plugin: str) -> type:
    """Class ``name``: ``mixin``'s attributes on ``base`` (a class of the current variant),
    registered with ``register(plugin, factory)`` (e.g. ``mi.register_bsdf``); built once per
    variant, later calls return the same class."""
    key = (mi.variant(), name)
    if key not in _CLASSES:
        # the mixin's attributes and those of the plain classes it derives from (later ones win)
        attrs = {k: v for klass in reversed(mixin.__mro__[:-1]) for k, v in vars(klass).items() if k not in _OWN}
        cls = type(name, (base,), attrs)
        register(plugin, lambda props: cls(props))
        _CLASSES[key] = cls
    return _CLASSES[key]
