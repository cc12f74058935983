"""Kernel BRDFs (paper eq. 3-4): parameterless basis BRDFs f_i, weighted per segment by ρ_i.

A kernel is registered by name. It knows

* its *unit-weight* BSDF (ρ = 1), which the polynomial integrator evaluates and samples, and
* its Mitsuba BSDF at weight ρ, so that a segment's kernel BRDF Σ_i ρ_i f_i becomes one exact
  Mitsuba BSDF for forward rendering (:func:`forward_bsdf`).

Every BSDF is wrapped in ``twosided``: scanned meshes have inconsistently wound faces and a
one-sided BSDF is black from behind.

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
    parameter : str
        The Mitsuba parameter of ``weighted_bsdf`` that carries ρ (for ``mi.traverse`` updates).
    """

    name: str
    delta: bool
    weighted_bsdf: Callable[[object], dict]
    parameter: str

    def unit_bsdf(self) -> dict:
        """Two-sided BSDF dict of the kernel at unit weight (ρ = 1)."""
        return {"type": "twosided", "bsdf": self.weighted_bsdf(1.0)}


KERNELS: dict[str, Kernel] = {}


def register(kernel: Kernel) -> Kernel:
    KERNELS[kernel.name] = kernel
    return kernel


register(Kernel("diffuse", delta=False, parameter="reflectance.value",
                weighted_bsdf=lambda rho: {"type": "diffuse", "reflectance": rho}))
register(Kernel("specular", delta=True, parameter="specular_reflectance.value",
                weighted_bsdf=lambda rho: {"type": "conductor", "material": "none",
                                           "specular_reflectance": rho}))


def get(name: str) -> Kernel:
    """The registered kernel ``name``; :class:`SceneError` listing the known names otherwise."""
    try:
        return KERNELS[name]
    except KeyError:
        raise SceneError(f"unknown kernel '{name}': use one of {', '.join(sorted(KERNELS))}") from None


def forward_bsdf(kernels: list[str], channels: tuple[str, ...]) -> dict:
    """Mitsuba BSDF dict whose parameters :func:`weight_values` sets to Σ_i ρ_i f_i, exactly.

    Mitsuba's ``blendbsdf`` computes (1-w)·f_a + w·f_b, so K kernels are blended with equal
    shares and each component's ρ is scaled by K: component i then contributes exactly ρ_i f_i,
    channel by channel. Mitsuba refuses RGB reflectances above 1 at load time but not through
    ``mi.traverse``, so the dict holds placeholders (0.5) and the weights are written after
    loading (see :func:`framework.mitsuba_scene.set_weights`).
    """
    parts = [get(k).weighted_bsdf(spectrum(0.5, channels)) for k in kernels]
    return {"type": "twosided", "bsdf": _blend(parts)}


def _blend(parts: list[dict]) -> dict:
    if len(parts) == 1:
        return parts[0]
    n = len(parts)
    # (1 - w)·f_0 + w·rest, with w = (n-1)/n: f_0 keeps share 1/n, each of the rest 1/n too.
    return {"type": "blendbsdf", "weight": (n - 1) / n, "bsdf_0": parts[0], "bsdf_1": _blend(parts[1:])}


def weight_values(kernels: list[str], rho: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """(traverse key relative to the shape's ``bsdf``, value) per kernel: the value is K·ρ_i.

    ``rho`` has shape (len(kernels), n_channels); keys look like
    ``brdf_0.bsdf_1.bsdf_0.reflectance.value``.
    """
    K = len(kernels)
    rho = np.asarray(rho, dtype=float).reshape(K, -1)
    out = []
    for i, k in enumerate(kernels):
        path = "brdf_0." + "bsdf_1." * i + ("bsdf_0." if K > 1 and i < K - 1 else "")
        out.append((path + get(k).parameter, K * rho[i]))
    return out
