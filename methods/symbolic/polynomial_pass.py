"""One polynomial rendering pass over all views: Gram systems and sparse coefficients, cached.

The pass renders every view once with :class:`PolynomialPathIntegrator`, tile by tile, and
adds each tile's pixels to the Gram system (G, b, yy) of the cost (paper eq. 6, p = 2); memory
is bounded by the tile (chosen from ``memory_mb``) and N_e², never by pixels or views. Per-pixel
coefficients are kept only as sparse matrices (2-6 % non-zero), to rebuild reconstructions.

Render once, solve many: the result of each view is cached on disk, keyed by everything that
affects it (scene content, view, spp, seed, N_max, parameters, guesses, selection floor, variant).
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from framework.cache import Cache
from framework.observe import inversion_seed
from methods.symbolic.basis import MonomialBasis
from methods.symbolic.gram import GramSystem

log = logging.getLogger(__name__)
BYTES_PER_COEFFICIENT = 4 * 3   # float32 buffer + Dr.Jit temporaries during scatter and readback


@dataclass
class PassResult:
    system: GramSystem                                   # summed over views
    systems: dict[str, GramSystem]                       # per view
    coefficients: dict[str, list[sp.csr_matrix]]         # view -> per channel (n_pix, N_e)
    render_s: float = 0.0
    from_cache: list[str] = field(default_factory=list)  # views read from the cache

    def image(self, view: str, mu: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """The polynomial image of ``view`` at monomials ``mu`` (C, N_e): (H, W, C) float32."""
        chans = [self.coefficients[view][c] @ mu[c] for c in range(len(mu))]
        return np.stack(chans, axis=-1).reshape(*shape, len(mu)).astype(np.float32)


def tile_pixels_for(memory_mb: float, n_monomials: int, n_channels: int) -> int:
    """Largest tile whose coefficient buffers fit in ``memory_mb`` (at least 64 pixels)."""
    return max(64, int(memory_mb * 2**20 // (n_monomials * n_channels * BYTES_PER_COEFFICIENT)))


def polynomial_pass(problem, parameters, guesses: np.ndarray, basis: MonomialBasis, *, spp: int,
                    seed: int, prob_floor: float, memory_mb: float, cache: Cache) -> PassResult:
    """Gram systems and coefficients of every view of ``problem`` (one render in total)."""
    from framework.mitsuba_scene import MitsubaScene
    from methods.symbolic.integrator import PolynomialPathIntegrator

    scene, C = problem.scene, problem.n_channels
    systems, coeffs, cached = {}, {}, []
    todo = []
    for i, cam in enumerate(problem.cameras):
        key = _key(problem, cam, parameters, guesses, spp, seed, prob_floor, basis, view=i)
        hit = cache.load("polynomial_pass", key)
        if hit is None:
            todo.append((i, cam, key))
            continue
        systems[cam.name], coeffs[cam.name] = _unpack(hit, C)
        cached.append(cam.name)
    t0 = time.perf_counter()
    if todo:
        ms = MitsubaScene(scene, problem.cameras, spp=spp)
        segment_kernels = [[(p.kernel, p.index) for p in parameters if p.segment == s]
                           for s in range(len(scene.segments))]
        integrator = PolynomialPathIntegrator.create(
            ms.shape_segments, segment_kernels, len(parameters), guesses,
            max_bounces=basis.max_degree, prob_floor=prob_floor,
            tile_pixels=tile_pixels_for(memory_mb, basis.size, C))
        for i, cam, key in todo:
            system, mats = _render_view(integrator, ms, i, cam, problem.observed[cam.name], basis, spp,
                                        inversion_seed(seed, i))
            cache.store("polynomial_pass", key, _pack(system, mats))
            systems[cam.name], coeffs[cam.name] = system, mats
    render_s = time.perf_counter() - t0
    total = GramSystem.zeros(basis.size, C)
    for s in systems.values():
        total = total + s
    return PassResult(total, systems, coeffs, render_s, cached)


def _render_view(integrator, ms, i, cam, observed, basis, spp, seed):
    """Tile by tile: accumulate the Gram system and keep sparse coefficients."""
    from tqdm import tqdm
    C = observed.shape[-1]
    n_pix = cam.width * cam.height
    y = observed.reshape(n_pix, C)
    system = GramSystem.zeros(basis.size, C)
    parts = [[] for _ in range(C)]
    tiles = range(0, n_pix, integrator.tile_pixels)
    for start in tqdm(tiles, desc=f"polynomial pass {cam.name}", unit="tile", leave=False):
        stop = min(n_pix, start + integrator.tile_pixels)
        gamma = integrator.coefficients(ms.scene, i, spp=spp, seed=seed, pixel_range=(start, stop))
        system.accumulate(gamma, y[start:stop])
        for c in range(C):
            parts[c].append(sp.csr_matrix(gamma[:, :, c]))
    return system, [sp.vstack(p, format="csr") for p in parts]


def _key(problem, cam, parameters, guesses, spp, seed, prob_floor, basis, *, view: int) -> dict:
    return {"scene": problem.scene.content_hash, "view": cam.name, "view_index": view, "spp": int(spp),
            "seed": int(seed), "max_bounces": int(basis.max_degree),
            "parameters": [[p.segment, p.kernel] for p in parameters],
            "guesses": np.round(np.asarray(guesses, float), 9).tolist(), "prob_floor": float(prob_floor),
            "observed": _digest(problem.observed[cam.name]),
            "variant": str(problem.settings.get("variant_resolved", "")), "version": 1}


def _digest(a: np.ndarray) -> str:
    import hashlib
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]


def _pack(system: GramSystem, mats: list[sp.csr_matrix]) -> dict[str, np.ndarray]:
    out = {"G": system.G, "b": system.b, "yy": system.yy, "n_pixels": np.array(system.n_pixels)}
    for c, m in enumerate(mats):
        out.update({f"c{c}_data": m.data, f"c{c}_indices": m.indices, f"c{c}_indptr": m.indptr,
                    f"c{c}_shape": np.array(m.shape)})
    return out


def _unpack(arrays: dict, C: int) -> tuple[GramSystem, list[sp.csr_matrix]]:
    system = GramSystem(arrays["G"], arrays["b"], arrays["yy"], int(arrays["n_pixels"]))
    mats = [sp.csr_matrix((arrays[f"c{c}_data"], arrays[f"c{c}_indices"], arrays[f"c{c}_indptr"]),
                          shape=tuple(arrays[f"c{c}_shape"])) for c in range(C)]
    return system, mats
