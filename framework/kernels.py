"""Kernel BRDFs (paper eq. 3-4): parameterless basis BRDFs f_i, weighted per segment by ρ_i.

A kernel is registered by name. It knows

* its *unit-weight* BSDF (ρ = 1), which the polynomial integrator evaluates and samples, and
* its one-sided Mitsuba BSDF at weight ρ (``weighted_bsdf``); a segment's kernel BRDF
  Σ_i ρ_i f_i is one exact, two-sided Mitsuba BSDF for forward rendering
  (:func:`framework.render.kernel_bsdf.forward_bsdf`).

This module imports no Mitsuba: the scene loader checks kernel names with it.

Every BSDF is two-sided: scanned meshes have inconsistently wound faces and a one-sided BSDF
is black from behind.

Registered kernels
------------------
``diffuse``   f = 1/π (Lambertian); Mitsuba ``diffuse`` with ``reflectance`` ρ_d.
``specular``  perfect mirror of reflectance ρ_s; Mitsuba ``conductor`` with ``material: none``
              (Fresnel factor 1) and ``specular_reflectance`` ρ_s.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from framework.errors import SceneError


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
        Registry name used in ``scene.yaml``.
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


KERNELS: dict[str, Kernel] = {}


def register(kernel: Kernel) -> Kernel:
    KERNELS[kernel.name] = kernel
    return kernel


register(Kernel("diffuse", delta=False,
                weighted_bsdf=lambda rho: {"type": "diffuse", "reflectance": rho}))
register(Kernel("specular", delta=True,
                weighted_bsdf=lambda rho: {"type": "conductor", "material": "none",
                                           "specular_reflectance": rho}))


def get(name: str) -> Kernel:
    """The registered kernel ``name``; :class:`SceneError` listing the known names otherwise."""
    try:
        return KERNELS[name]
    except KeyError:
        raise SceneError(f"unknown kernel '{name}': use one of {', '.join(sorted(KERNELS))}") from None
