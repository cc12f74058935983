"""Clear-sky illumination of the bundled scenes: Mitsuba's ``sunsky`` baked by
:mod:`framework.render.sunsky` (an equirectangular sky without its sun, and the sun as a
``directional`` emitter; mono scenes take the 550 nm band).

The bundled skies were baked with ``sunsky``'s own ground albedo for the sky model
(:data:`~framework.render.sunsky.MITSUBA_ALBEDO`, 0.3) and a Lambertian ground of albedo 0.2
below the horizon; :func:`bake_sky` keeps that, so the committed ``sky.exr`` files are what
``python -m scenes.build`` writes. (A ``sunsky`` emitter in scene.yaml uses its one
``ground_albedo`` for both.)
"""
from __future__ import annotations

import numpy as np

from framework.render import sunsky
from framework.render.sunsky import sun_irradiance, sun_vector

__all__ = ["bake_sky", "sun_irradiance", "sun_vector"]


def bake_sky(sun: np.ndarray, height: int, width: int, channels: str = "rgb",
             turbidity: float = 3.0, ground_albedo: float = 0.2) -> np.ndarray:
    """:func:`framework.render.sunsky.bake_sky` with the sky model's albedo at Mitsuba's default."""
    return sunsky.bake_sky(sun, height, width, channels, turbidity, ground_albedo,
                           sky_albedo=sunsky.MITSUBA_ALBEDO)
