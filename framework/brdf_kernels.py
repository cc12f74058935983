"""Kernel BRDFs (paper eq. 3-4): basis BRDFs f_i, weighted per segment by ρ_i.

A kernel is registered by name. It knows

* its *unit-weight* BSDF (ρ = 1), which the polynomial integrator evaluates and samples, and
* its one-sided Mitsuba BSDF at weight ρ (``weighted_bsdf``); a segment's kernel BRDF
  Σ_i ρ_i f_i is one exact, two-sided Mitsuba BSDF for forward rendering
  (:func:`framework.render.kernel_bsdf.forward_bsdf`).

A kernel has no free parameter besides its weight ρ, so every pixel stays a polynomial in ρ. A
*family* of kernels takes one fixed number in parentheses, ``name(<number>)`` (``glossy(0.15)``):
each value is its own kernel, written the same way in ``scene.yaml`` (``kernels``, ``reference``)
and in results.

This module imports no Mitsuba: the scene loader checks kernel names with it.

Every BSDF is two-sided: scanned meshes have inconsistently wound faces and a one-sided BSDF
is black from behind.

Registered kernels
------------------
``diffuse``    f = 1/π (Lambertian); Mitsuba ``diffuse`` with ``reflectance`` ρ_d.
``specular``   perfect mirror of reflectance ρ_s; Mitsuba ``conductor`` with ``material: none``
               (Fresnel factor 1) and ``specular_reflectance`` ρ_s.
``glossy(α)``  GGX microfacet lobe of fixed roughness α in (0, 1], Fresnel factor 1, weighted
               by ρ_g; Mitsuba ``roughconductor`` with ``distribution: ggx``, ``alpha`` α,
               ``material: none`` and ``specular_reflectance`` ρ_g. Single-scattering GGX
               loses energy to masking: the unit lobe's albedo at normal incidence is 0.997 at
               α = 0.05, 0.988 at 0.1, 0.948 at 0.2, 0.877 at 0.3, 0.688 at 0.5 (quadrature of
               D G1 G1 / (4 cos θ_i)); 1 only as α -> 0. α is a fixed part of the kernel's name,
               not an unknown: ``glossy(0.05)`` and ``glossy(0.3)`` are two kernels.

Names of a family
-----------------
``get`` parses ``name(<number>)`` with Python's ``float`` (``glossy(0.15)``, ``glossy(1.5e-1)``),
checks the range and returns the kernel of the *canonical* name ``name(repr(float(number)))``:
``glossy(0.150)`` and ``glossy(0.15)`` are the same :class:`Kernel` object, whose ``name`` is
``glossy(0.15)``. Scenes, references and results keep the name as written (the scene loader
checks names but does not rewrite them), so a reference must be keyed by the name exactly as the
segment's ``kernels`` write it; writing the canonical form keeps scene files and results alike.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Callable

import numpy as np

from framework.errors import ConfigError, SceneError
from framework.options import Check


def spectrum(value, channels: tuple[str, ...]) -> dict | float:
    """A Mitsuba spectrum property for one value per channel (``rgb`` dict, or a float for mono)."""
    v = np.broadcast_to(np.asarray(value, dtype=float), (len(channels),))
    if channels == ("Y",):
        return float(v[0])
    return {"type": "rgb", "value": [float(x) for x in v]}


@dataclass(frozen=True)
class Kernel:
    """One basis BRDF of the kernel model.

    Parameters
    ----------
    name : str
        Registry name used in ``scene.yaml`` (canonical for a family: ``glossy(0.15)``).
    delta : bool
        True for Dirac lobes (no next-event estimation through them).
    weighted_bsdf : callable
        ``weighted_bsdf(rho_spectrum) -> dict``: the one-sided Mitsuba BSDF dict of ρ·f.
    """

    name: str
    delta: bool
    weighted_bsdf: Callable[[object], dict]

    def unit_bsdf(self) -> dict:
        """Two-sided BSDF dict of the kernel at unit weight (ρ = 1)."""
        return {"type": "twosided", "bsdf": self.weighted_bsdf(1.0)}


@dataclass(frozen=True)
class Family:
    """Kernels of one parameter, written ``name(<number>)``.

    Parameters
    ----------
    name : str
        The family name before the parentheses.
    low, high : float
        The allowed parameter range ``(low, high]``.
    example : float
        A value shown in error messages.
    what : str
        What the parameter is, for messages (``GGX roughness``).
    make : callable
        ``make(canonical_name, value) -> Kernel``.
    """

    name: str
    low: float
    high: float
    example: float
    what: str
    make: Callable[[str, float], Kernel]

    def usage(self) -> str:
        """``glossy(α) (GGX roughness α in (0, 1], e.g. glossy(0.15))``."""
        return f"{self.name}(α) ({self.what} α in ({self.low:g}, {self.high:g}], e.g. {self.name}({self.example}))"


class _Registry(dict):
    """Name -> kernel of the parameterless kernels; ``in`` and ``[]`` also accept every valid name
    of a family (``"glossy(0.2)" in KERNELS``), which iteration does not list."""

    def __contains__(self, name) -> bool:
        if dict.__contains__(self, name):
            return True
        try:
            return _family_kernel(str(name)) is not None
        except SceneError:
            return False

    def __missing__(self, name):
        try:
            kernel = _family_kernel(str(name))
        except SceneError:
            kernel = None
        if kernel is None:
            raise KeyError(name)
        return kernel


KERNELS: dict[str, Kernel] = _Registry()
FAMILIES: dict[str, Family] = {}
_INSTANCES: dict[str, Kernel] = {}       # canonical name -> kernel of a family, built once
_CALL = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*\((.*)\)\s*$", re.DOTALL)


def register(kernel: Kernel) -> Kernel:
    KERNELS[kernel.name] = kernel
    return kernel


def register_family(family: Family) -> Family:
    FAMILIES[family.name] = family
    return family


def _glossy(name: str, alpha: float) -> Kernel:
    return Kernel(name, delta=False,
                  weighted_bsdf=lambda rho: {"type": "roughconductor", "distribution": "ggx", "alpha": alpha,
                                             "material": "none", "specular_reflectance": rho})


register(Kernel("diffuse", delta=False,
                weighted_bsdf=lambda rho: {"type": "diffuse", "reflectance": rho}))
register(Kernel("specular", delta=True,
                weighted_bsdf=lambda rho: {"type": "conductor", "material": "none",
                                           "specular_reflectance": rho}))
register_family(Family("glossy", 0.0, 1.0, 0.15, "GGX roughness", _glossy))


def known() -> str:
    """The registered names for messages: ``diffuse, specular, glossy(α) (GGX roughness α in ...)``."""
    return ", ".join([*dict.keys(KERNELS), *(f.usage() for f in FAMILIES.values())])


def canonical(name: str) -> str:
    """The canonical name of a valid kernel name (``glossy(0.150)`` -> ``glossy(0.15)``)."""
    return get(name).name


def _family_kernel(name: str) -> Kernel | None:
    """The kernel of a family name ``name(<number>)``, None if ``name`` is not of that form;
    :class:`SceneError` for a bad parameter or a parameter on a parameterless kernel."""
    m = _CALL.match(name)
    if m is None:
        return None
    base, arg = m.group(1), m.group(2).strip()
    family = FAMILIES.get(base)
    if family is None:
        if dict.__contains__(KERNELS, base):
            raise SceneError(f"kernel '{name}': {base} takes no parameter; write {base} (a kernel with a "
                             f"parameter: {', '.join(f.usage() for f in FAMILIES.values())})")
        return None
    try:
        value = float(arg)
    except ValueError:
        raise SceneError(f"kernel '{name}': '{arg}' is not a number; {base} takes its {family.what} α in "
                         f"({family.low:g}, {family.high:g}] in parentheses, e.g. {base}({family.example})") from None
    if not family.low < value <= family.high:     # NaN fails too
        raise SceneError(f"kernel '{name}': {family.what} α = {arg} is outside ({family.low:g}, {family.high:g}]; "
                         f"write e.g. {base}({family.example})")
    canon = f"{base}({value!r})"
    if canon not in _INSTANCES:
        _INSTANCES[canon] = family.make(canon, value)
    return _INSTANCES[canon]


def get(name: str) -> Kernel:
    """The kernel ``name``: a registered one, or a family member ``name(<number>)`` (its canonical
    kernel, built once); :class:`SceneError` naming the kernel and the allowed names otherwise."""
    name = str(name)
    if dict.__contains__(KERNELS, name):
        return dict.__getitem__(KERNELS, name)
    kernel = _family_kernel(name)
    if kernel is not None:
        return kernel
    if name.strip() in FAMILIES:
        f = FAMILIES[name.strip()]
        raise SceneError(f"unknown kernel '{name}': {f.name} needs its {f.what} α in ({f.low:g}, {f.high:g}] "
                         f"in parentheses, e.g. {f.name}({f.example})")
    raise SceneError(f"unknown kernel '{name}': use one of {known()}")


def _selection(key: str, value) -> tuple[str, ...] | None:
    """``method.kernels``: ``all`` (None) or a non-empty list of registered kernel names, returned
    canonical (``glossy(0.150)`` is ``glossy(0.15)``)."""
    from omegaconf import ListConfig
    if value == "all":
        return None
    if not isinstance(value, (list, tuple, ListConfig)):
        raise ConfigError(f"{key}={value} is not a list: use all, or a list such as {key}=[{value}]")
    unknown = [str(k) for k in value if str(k) not in KERNELS]
    if unknown or not value:
        what = f"has unknown kernel(s) {', '.join(unknown)}" if unknown else "is empty"
        raise ConfigError(f"{key} {what}: use all, or a list of the registered kernels "
                          f"({', '.join(sorted(KERNELS))})")
    return tuple(canonical(str(k)) for k in value)


#: the check of a kernel selection option (``method.kernels``)
KERNEL_SELECTION = Check("`all` or a list of kernel names", _selection)
