"""Equirectangular environment maps in the scene format: image top = world +z (``docs/scene-format.md``).

Mitsuba's ``envmap`` is +y up in its local frame and maps a local direction v to
u = atan2(v_x, -v_z) / 2π, v = acos(v_y) / π. The scene format is +z up, so the emitter gets
``to_world`` = rotation of +90° about x (local +y -> world +z). With θ the zenith angle and φ
the azimuth measured from world +y towards world +x, texel (row i, column j) of an H x W map
looks along

    d = (sin φ sin θ, cos φ sin θ, cos θ),   θ = π (i + ½) / H,   φ = 2π (j + ½) / W.

:func:`texel_directions` gives these directions (to bake a sky); the tests check them against
Mitsuba's own ``envmap`` evaluation.
"""
from __future__ import annotations

import numpy as np

#: ``to_world`` of a Mitsuba ``envmap`` emitter for a +z-up map (rotation of +90° about x).
TO_WORLD = np.array([[1.0, 0.0, 0.0, 0.0],
                     [0.0, 0.0, -1.0, 0.0],
                     [0.0, 1.0, 0.0, 0.0],
                     [0.0, 0.0, 0.0, 1.0]])


def texel_directions(height: int, width: int) -> np.ndarray:
    """World direction (unit, +z up) seen at the centre of each texel, shape (height, width, 3)."""
    theta = np.pi * (np.arange(height) + 0.5) / height
    phi = 2 * np.pi * (np.arange(width) + 0.5) / width
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    return np.stack([np.sin(ph) * np.sin(th), np.cos(ph) * np.sin(th), np.cos(th)], axis=-1)


def texel_solid_angles(height: int, width: int) -> np.ndarray:
    """Solid angle of each texel (sr), shape (height, width); sums to 4π."""
    theta_edges = np.pi * np.arange(height + 1) / height
    band = np.cos(theta_edges[:-1]) - np.cos(theta_edges[1:])
    return np.repeat((band * 2 * np.pi / width)[:, None], width, axis=1)
