"""Clear-sky illumination baked from Mitsuba's ``sunsky`` emitter.

The sky (``sun_scale: 0``) is baked into an equirectangular map in the convention of
:mod:`framework.render.envmap` (image top = world +z): texel direction ``d`` gets ``emitter.eval`` of a
``SurfaceInteraction3f`` with ``wi = -d``. The sun becomes a ``directional`` emitter whose
irradiance is the sun disk's radiance integrated over its solid angle (``sky_scale: 0``).

Colour modes: ``rgb`` evaluates the ``llvm_ad_rgb`` variant of ``sunsky``; ``mono`` evaluates the
``llvm_ad_spectral`` variant with every wavelength set to 550 nm (the paper's band): the
``mono`` variants refuse ``sunsky``. Both are in Mitsuba's units, W m^-2 sr^-1 nm^-1
(irradiance W m^-2 nm^-1), used at scale 1.

Below the horizon, ``sunsky`` returns 0; the bake puts there the radiance of a Lambertian
ground of albedo ``ground_albedo`` lit by the same sun and sky, (ρ_g / π)·(E_sun,h + E_sky,h).
"""
from __future__ import annotations

import numpy as np

from framework.render.backend import set_variant
from framework.render.envmap import texel_directions, texel_solid_angles

SUN_HALF_APERTURE_DEG = 0.5358 / 2   # sunsky's default sun_aperture (degrees, full angle)


def sun_vector(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """Unit direction towards the sun; azimuth from world +y towards +x (as framework.render.envmap)."""
    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    return np.array([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)])


def _variant(channels: str) -> str:
    return set_variant("llvm_ad_rgb" if channels == "rgb" else "llvm_ad_spectral")


def _eval(emitter, directions: np.ndarray, channels: str) -> np.ndarray:
    """Radiance (n, c) arriving from each direction (n, 3) for the current variant."""
    import drjit as dr
    import mitsuba as mi

    d = np.asarray(directions, np.float32)
    si = dr.zeros(mi.SurfaceInteraction3f, len(d))
    si.wi = mi.Vector3f(-d[:, 0], -d[:, 1], -d[:, 2])
    if channels == "mono":
        si.wavelengths = mi.Spectrum(550.0)
        return np.array(emitter.eval(si))[0][:, None]
    return np.array(emitter.eval(si)).T


def _sunsky(sun: np.ndarray, sun_scale: float, sky_scale: float, turbidity: float):
    import mitsuba as mi

    return mi.load_dict({"type": "sunsky", "sun_direction": [float(x) for x in sun],
                         "turbidity": turbidity, "sun_scale": sun_scale, "sky_scale": sky_scale})


def sun_irradiance(sun: np.ndarray, channels: str = "rgb", turbidity: float = 3.0,
                   n: int = 161) -> np.ndarray:
    """Irradiance (c,) of the sun disk on a plane facing it: its radiance integrated over a
    small tangent-plane grid of ``n x n`` directions covering the disk."""
    _variant(channels)
    emitter = _sunsky(sun, 1.0, 0.0, turbidity)
    r = np.tan(np.radians(SUN_HALF_APERTURE_DEG) * 1.2)
    u = np.cross(sun, [0.0, 0.0, 1.0] if abs(sun[2]) < 0.99 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(sun, u)
    s = np.linspace(-r, r, n)
    a, b = np.meshgrid(s, s, indexing="ij")
    d = sun + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    d_omega = (s[1] - s[0]) ** 2 / norm[:, 0] ** 3          # solid angle of a tangent-plane cell
    return (_eval(emitter, d / norm, channels) * d_omega[:, None]).sum(0)


def bake_sky(sun: np.ndarray, height: int, width: int, channels: str = "rgb",
             turbidity: float = 3.0, ground_albedo: float = 0.2) -> np.ndarray:
    """Equirectangular sky (height, width, c) of ``sunsky`` without its sun, ground below horizon.

    Parameters
    ----------
    sun : ndarray (3,)
        Unit direction towards the sun.
    height, width : int
        Map size (texel directions from :func:`framework.render.envmap.texel_directions`).
    channels : {'rgb', 'mono'}
        RGB, or the single 550 nm band.
    turbidity : float
        ``sunsky`` turbidity (3: clear sky).
    ground_albedo : float
        Albedo of the Lambertian ground seen below the horizon.
    """
    _variant(channels)
    dirs = texel_directions(height, width)
    sky = _eval(_sunsky(sun, 0.0, 1.0, turbidity), dirs.reshape(-1, 3), channels)
    sky = sky.reshape(height, width, -1)
    up = dirs[..., 2] > 0
    sky[~up] = 0.0
    cos = np.clip(dirs[..., 2], 0, None) * texel_solid_angles(height, width)
    e_sky = (sky * cos[..., None]).sum((0, 1))
    e_sun = sun_irradiance(sun, channels, turbidity) * max(sun[2], 0.0)
    sky[~up] = ground_albedo / np.pi * (e_sky + e_sun)
    return sky.astype(np.float32)
