"""Mitsuba's Hosek-Wilkie ``sunsky`` as the scene model's emitters: an equirectangular sky and a
``directional`` sun.

The sky (``sun_scale: 0``) is baked into an equirectangular map in the convention of
:mod:`framework.render.envmap` (image top = world +z): texel direction ``d`` gets ``emitter.eval``
of a ``SurfaceInteraction3f`` with ``wi = -d``. The sun becomes a ``directional`` emitter whose
irradiance is the sun disk's radiance integrated over its solid angle (``sky_scale: 0``).

Colour modes: ``rgb`` evaluates the ``*_ad_rgb`` variant of ``sunsky``; ``mono`` evaluates the
``*_ad_spectral`` variant with every wavelength set to 550 nm (the paper's band): the
``mono`` variants refuse ``sunsky``. ``*`` is the run's backend (:func:`framework.render.backend.jit_backend`:
``cuda`` on a GPU, else ``llvm``), so a GPU run needs no libLLVM. Both are in Mitsuba's units, W m^-2 sr^-1 nm^-1
(irradiance W m^-2 nm^-1), at scale 1. Each function selects the variant it needs and selects
the one that was active before again when it returns.

Below the horizon, ``sunsky`` returns 0; the bake puts there the radiance of a Lambertian
ground of albedo ``ground_albedo`` lit by the same sun and sky, (ρ_g / π)·(E_sun,h + E_sky,h).

The sun's place in the sky. With ``latitude``, ``longitude``, ``timezone`` and ``year`` ..
``second`` (the local civil time at that UTC offset), Mitsuba 3.9 computes the sun's zenith
angle θ and azimuth A (from north, towards east) with the PSA algorithm (Blanco-Muriel et al.
2001, no atmospheric refraction) and puts it at ``sphdir(θ, A - π)`` in the emitter's frame:
+z up, **north = -x, east = -y**. That frame is a mirror image of the sky (north x east = up,
where a right-handed z-up world has north x east = down), harmless for the sky, whose radiance
depends only on the angles to the zenith and to the sun, but not for the sun. So the emitter is
never placed with a ``to_world``: :func:`sun_position` reads Mitsuba's direction back as an
elevation and a compass azimuth, :func:`sun_vector` puts the sun in the world with the scene's
``north`` (east = north x up), and the sky is baked around that world direction.
"""
from __future__ import annotations

import functools
from contextlib import contextmanager
from datetime import datetime

import numpy as np

from framework.render.backend import jit_backend, set_variant
from framework.render.envmap import texel_directions, texel_solid_angles

SUN_HALF_APERTURE_DEG = 0.5358 / 2   # sunsky's default sun_aperture (degrees, full angle)
MITSUBA_ALBEDO = 0.3                 # sunsky's default ``albedo`` (the bundled skies were baked with it)
SKY_SIZE = (128, 256)                # (height, width) of the sky the scene loader bakes


def sun_vector(elevation_deg: float, azimuth_deg: float, *, north=(0.0, 1.0, 0.0)) -> np.ndarray:
    """Unit world direction towards the sun.

    Parameters
    ----------
    elevation_deg : float
        Angle above the horizon (the plane z = 0), degrees.
    azimuth_deg : float
        Compass azimuth, degrees: 0 towards ``north``, 90 towards east = north x up.
    north : array-like (3,), default (0, 1, 0)
        World direction of geographic north, horizontal (z = 0) and unit. With the default,
        the azimuth runs from world +y towards +x (as :mod:`framework.render.envmap`).
    """
    n = np.asarray(north, float)
    east = np.cross(n, [0.0, 0.0, 1.0])
    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    return np.cos(el) * (np.cos(az) * n + np.sin(az) * east) + np.array([0.0, 0.0, np.sin(el)])


@contextmanager
def _variant(channels: str):
    """The variant that evaluates ``sunsky`` for ``channels``, then the previous one again."""
    import mitsuba as mi
    previous = mi.variant()
    set_variant(f"{jit_backend()}_ad_{'rgb' if channels == 'rgb' else 'spectral'}")
    try:
        yield
    finally:
        if previous is not None and previous != mi.variant():
            mi.set_variant(previous)


def sun_position(latitude: float, longitude: float, time: datetime) -> tuple[float, float]:
    """Elevation and compass azimuth (degrees, azimuth from north towards east) of the sun seen
    from a place at a time, as Mitsuba's ``sunsky`` places it (PSA algorithm, no refraction).

    Parameters
    ----------
    latitude, longitude : float
        Degrees, north and east positive.
    time : datetime
        Aware (with its UTC offset): the local civil time at that offset, as ``sunsky`` takes it
        (``timezone`` = the offset in hours).
    """
    offset = time.utcoffset()
    if offset is None:
        raise ValueError("sun_position: time needs its UTC offset (an aware datetime)")
    import mitsuba as mi
    with _variant("rgb"):
        emitter = mi.load_dict({
            "type": "sunsky", "latitude": float(latitude), "longitude": float(longitude),
            "timezone": offset.total_seconds() / 3600.0, "year": time.year, "month": time.month,
            "day": time.day, "hour": float(time.hour), "minute": float(time.minute),
            "second": time.second + time.microsecond * 1e-6})
        d = np.array(mi.traverse(emitter)["sun_direction"], float).ravel()
    d /= np.linalg.norm(d)
    # Mitsuba's frame: north = -x, east = -y, up = +z (see the module docstring)
    elevation = np.degrees(np.arcsin(np.clip(d[2], -1.0, 1.0)))
    azimuth = np.degrees(np.arctan2(-d[1], -d[0])) % 360.0
    return float(elevation), float(azimuth)


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


def _sunsky(sun: np.ndarray, sun_scale: float, sky_scale: float, turbidity: float, albedo: float):
    import mitsuba as mi

    return mi.load_dict({"type": "sunsky", "sun_direction": [float(x) for x in sun],
                         "turbidity": float(turbidity), "albedo": float(albedo),
                         "sun_scale": sun_scale, "sky_scale": sky_scale})


def sun_irradiance(sun: np.ndarray, channels: str = "rgb", turbidity: float = 3.0,
                   n: int = 161) -> np.ndarray:
    """Irradiance (c,) of the sun disk on a plane facing it: its radiance integrated over a
    small tangent-plane grid of ``n x n`` directions covering the disk.

    Parameters
    ----------
    sun : ndarray (3,)
        Unit direction towards the sun (above the horizon).
    channels : {'rgb', 'mono'}
        RGB, or the single 550 nm band.
    turbidity : float
        ``sunsky`` turbidity, in [1, 10]. (The sun does not depend on the ground albedo.)
    n : int
        Grid size across the disk.
    """
    sun = np.asarray(sun, float)
    r = np.tan(np.radians(SUN_HALF_APERTURE_DEG) * 1.2)
    u = np.cross(sun, [0.0, 0.0, 1.0] if abs(sun[2]) < 0.99 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(sun, u)
    s = np.linspace(-r, r, n)
    a, b = np.meshgrid(s, s, indexing="ij")
    d = sun + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    d_omega = (s[1] - s[0]) ** 2 / norm[:, 0] ** 3          # solid angle of a tangent-plane cell
    with _variant(channels):
        emitter = _sunsky(sun, 1.0, 0.0, turbidity, MITSUBA_ALBEDO)
        return (_eval(emitter, d / norm, channels) * d_omega[:, None]).sum(0)


def bake_sky(sun: np.ndarray, height: int, width: int, channels: str = "rgb",
             turbidity: float = 3.0, ground_albedo: float = 0.2, *,
             sky_albedo: float | None = None) -> np.ndarray:
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
        ``sunsky`` turbidity, in [1, 10] (3: clear sky).
    ground_albedo : float
        Albedo of the Lambertian ground seen below the horizon.
    sky_albedo : float, optional
        The ground albedo of the sky model (``sunsky``'s ``albedo``: light the ground sends back
        into the atmosphere); default ``ground_albedo``. The bundled scenes were baked with
        Mitsuba's default, :data:`MITSUBA_ALBEDO`.
    """
    sun = np.asarray(sun, float)
    dirs = texel_directions(height, width)
    with _variant(channels):
        albedo = ground_albedo if sky_albedo is None else sky_albedo
        sky = _eval(_sunsky(sun, 0.0, 1.0, turbidity, albedo), dirs.reshape(-1, 3), channels)
    sky = sky.reshape(height, width, -1)
    up = dirs[..., 2] > 0
    sky[~up] = 0.0
    cos = np.clip(dirs[..., 2], 0, None) * texel_solid_angles(height, width)
    e_sky = (sky * cos[..., None]).sum((0, 1))
    e_sun = sun_irradiance(sun, channels, turbidity) * max(sun[2], 0.0)
    sky[~up] = ground_albedo / np.pi * (e_sky + e_sun)
    return sky.astype(np.float32)


def sunsky_parts(sun: np.ndarray, channels: str, *, turbidity: float, ground_albedo: float,
                 size: tuple[int, int] = SKY_SIZE) -> tuple[np.ndarray, np.ndarray]:
    """The sky (``size`` + (c,), float32, see :func:`bake_sky`) and the sun's irradiance (c,) of a
    ``sunsky`` whose sun lies in direction ``sun``; ``ground_albedo`` serves the sky model and
    the ground below the horizon alike.

    Results are kept for the life of the process (one bake per distinct set of arguments: a
    scene loaded twice is baked once); nothing is written to disk.
    """
    sky, e_sun = _parts(tuple(float(x) for x in sun), channels, float(turbidity), float(ground_albedo),
                        tuple(size))
    return sky.copy(), e_sun.copy()


@functools.lru_cache(maxsize=16)
def _parts(sun: tuple, channels: str, turbidity: float, ground_albedo: float, size: tuple):
    v = np.array(sun)
    return (bake_sky(v, *size, channels, turbidity, ground_albedo),
            sun_irradiance(v, channels, turbidity))
