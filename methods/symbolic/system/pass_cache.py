"""The polynomial pass in the cache: each view's tiles of coefficients and its index.

Render once, solve many: the coefficients of each view are cached on disk, keyed by everything
that affects them (scene content, view, spp, seed, N_max, parameters, guesses, selection floor,
variant, observed pixels); a cached view's Gram system is rebuilt from them by the same function
as a rendered one's (:func:`~methods.symbolic.system.view_systems.weighted_system`), so a cached run gives the
same bits as the run that rendered. Tiles are written as they are rendered (by the worker, in a
background thread: :class:`TileWriter`) and read back one at a time (:class:`TileLoader`).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from framework.cache import Cache, code_version
from framework.observe import OBSERVED_CODE
from framework.threads import Chain
from methods.symbolic.system.coefficients import TiledCoefficients, ViewCoefficients
from methods.symbolic.system.emitter_groups import unknown_emitters
from methods.symbolic.system.gram import GramSystem
from methods.symbolic.system.view_systems import weighted_system


def empty_system(C: int) -> GramSystem:
    """No pixel yet, over the constant monomial (code 0), which every system holds."""
    return GramSystem.zeros(np.zeros(1, np.int64), C)


def cached_view(cache: Cache, key: dict, y: np.ndarray, C: int):
    """``(GramSystem, TiledCoefficients)`` of a view whose pass the cache holds, its Gram system
    rebuilt tile by tile from the stored coefficients; None when the index or a tile is missing
    or corrupt (the view is then rendered again)."""
    index = cache.load("polynomial_pass", key)
    if index is None or "starts" not in index:
        return None
    starts, n_rows = [int(s) for s in index["starts"]], int(index["n_rows"])
    system = empty_system(C)
    for k, (start, stop) in enumerate(zip(starts, starts[1:] + [n_rows])):
        hit = cache.load("polynomial_tile", tile_key(key, k))
        if hit is None:
            return None
        system += weighted_system(_unpack(hit, C), y[start:stop], None)
    return system, stored_view(cache, key, starts, n_rows, C)


def stored_view(cache: Cache, key: dict, starts: list, n_rows: int, C: int) -> TiledCoefficients:
    """The view's coefficients as blocks loaded from the cache when iterated."""
    return TiledCoefficients(starts, [TileLoader(cache.dir, tile_key(key, k), C) for k in range(len(starts))],
                             n_rows)


class TileWriter:
    """``store(k, block)`` of :func:`_render_view` that writes each tile to the cache in a
    background thread while the next tile renders (measured on the 1920x1080 view: the writes
    were 7 of the pass's 70 s), one tile in flight at most (:class:`~framework.threads.Chain`);
    :meth:`close` waits for the last and raises what a write raised."""

    def __init__(self, cache: Cache, key: dict, C: int):
        self.cache, self.key, self.C = cache, key, int(C)
        self._writes = Chain(name="tile-writer")

    def __call__(self, k: int, block: ViewCoefficients) -> "TileLoader":
        self._writes.then(lambda _: store_tile(self.cache, self.key, k, block, self.C))
        return tile_loader(self.cache, self.key, k, self.C)

    def close(self) -> None:
        with self._writes:
            self._writes.result()


def store_tile(cache: Cache, key: dict, k: int, block: ViewCoefficients, C: int) -> "TileLoader":
    """Store tile ``k`` of the view ``key``; the loader that reads it back."""
    cache.store("polynomial_tile", tile_key(key, k), _pack(block))
    return tile_loader(cache, key, k, C)


def tile_loader(cache: Cache, key: dict, k: int, C: int) -> "TileLoader":
    """The loader of tile ``k`` of the view ``key`` (stored or being stored)."""
    return TileLoader(cache.dir, tile_key(key, k), C)


#: the code a cached pass depends on (:func:`~framework.cache.code_version`): the observations'
#: and the pass's own packages. An edit of any of it, or another Mitsuba or Dr.Jit, renders the
#: pass again; the solver's packages are left out, so that solving again reads the pass back
PASS_CODE = OBSERVED_CODE + ("methods.symbolic.trace", "methods.symbolic.system")


def tile_key(key: dict, k: int) -> dict:
    return {**key, "tile": int(k)}


def view_key(problem, cam, parameters, guesses, spp, seed, prob_floor, max_bounces, *, view: int, cross_gram: bool,
             tail_bounces: int, footprint: str | None = None, quarters: bool = False) -> dict:
    return {"scene": problem.scene.content_hash, "view": cam.name, "view_index": view, "spp": int(spp),
            "seed": int(seed), "max_bounces": int(max_bounces),
            "parameters": [[p.segment, p.kernel] for p in parameters],
            "guesses": np.round(np.asarray(guesses, float), 9).tolist(), "prob_floor": float(prob_floor),
            "observed": _digest(problem.observed[cam.name]),
            "variant": problem.settings.variant, "cross_gram": bool(cross_gram),
            "tail_bounces": int(tail_bounces), "code": code_version(*PASS_CODE), "camera": camera_key(cam),
            "footprint": [footprint, _distortion(cam) if footprint else None],
            "unknown_scales": unknown_emitters(problem.scene),
            "quarters": bool(quarters)}


def footprint_kernel(problem, cam) -> str | None:
    """The interpolation (``photometry.resampling``) the loader resampled ``cam``'s photographs
    with, which the pass then integrates over
    (:meth:`framework.scene.undistort.Resampling.footprint`); None where the photographs are used
    as they are (a pinhole camera, or observations rendered by the framework with the pinhole)."""
    if problem.scene.images is None or getattr(cam, "distortion", None) is None:
        return None
    return problem.scene.photometry.resampling


def _distortion(cam) -> list | None:
    d = getattr(cam, "distortion", None)
    return None if d is None else [d[0], [float(x) for x in d[1]]]


def camera_key(cam) -> list:
    """The camera's pose and pinhole, in the pass's key: a view whose camera was corrected
    (:mod:`methods.symbolic.misfit.alignment`) keeps its name but renders other pixels."""
    pinhole = [int(cam.width), int(cam.height), float(cam.f), float(cam.cx), float(cam.cy)]
    return pinhole + np.round(np.asarray(cam.cam_from_world, float), 12).ravel().tolist()


def observed_pixels(problem, cam) -> np.ndarray:
    """``(pixels, C)`` observed radiance of ``cam``."""
    return np.asarray(problem.observed[cam.name]).reshape(cam.width * cam.height, -1)


def _digest(a: np.ndarray) -> str:
    import hashlib
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]


def _pack(coeffs: ViewCoefficients) -> dict[str, np.ndarray]:
    """The cache entry of a tile: its coefficients (its Gram system is rebuilt from them and the
    observed pixels, :func:`~methods.symbolic.system.view_systems.weighted_system`: a third of the bytes)."""
    out = {"codes": coeffs.codes, "split": np.array(coeffs.split)}
    for prefix, mats in (("a", coeffs.a), ("b", coeffs.b or []), ("qa", coeffs.a1 or []), ("qb", coeffs.b1 or [])):
        for c, m in enumerate(mats):
            out.update({f"{prefix}{c}_data": m.data, f"{prefix}{c}_indices": m.indices,
                        f"{prefix}{c}_indptr": m.indptr, f"{prefix}{c}_shape": np.array(m.shape)})
    return out


class TileLoader:
    """Reads a tile's :class:`ViewCoefficients` back from the cache folder when called; plain
    data, so a Dask worker that stored the tile can return it in place of the tile.

    Its quarters (``a1``, ``b1``, ``method.bias=richardson``) are read only by the loader
    :meth:`with_quarters` gives, which the half passes use: a fit of the whole pass does not
    need them, and they are half a tile's bytes."""

    def __init__(self, cache_dir, key: dict, C: int, quarters: bool = False):
        self.cache_dir, self.key, self.C, self.quarters = cache_dir, key, int(C), bool(quarters)

    def with_quarters(self) -> "TileLoader":
        return TileLoader(self.cache_dir, self.key, self.C, quarters=True)

    def __call__(self) -> ViewCoefficients:
        cache = Cache(self.cache_dir)
        keep = None if self.quarters else (lambda name: not name.startswith(("qa", "qb")))
        hit = cache.load("polynomial_tile", self.key, keep=keep)
        if hit is None:
            raise RuntimeError(f"cache entry of {self.key['view']} (tile {self.key['tile']}) vanished from "
                               f"{cache.dir} during the run")
        return _unpack(hit, self.C)


def _unpack(arrays: dict, C: int) -> ViewCoefficients:
    def mats(prefix):
        return [sp.csr_matrix((arrays[f"{prefix}{c}_data"], arrays[f"{prefix}{c}_indices"],
                               arrays[f"{prefix}{c}_indptr"]), shape=tuple(arrays[f"{prefix}{c}_shape"]))
                for c in range(C)]
    codes = np.asarray(arrays["codes"], np.int64)
    b, a1, b1 = (mats(p) if f"{p}0_data" in arrays else None for p in ("b", "qa", "qb"))
    return ViewCoefficients(mats("a"), b, float(arrays["split"]), codes, a1, b1)
