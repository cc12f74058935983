"""One polynomial rendering pass over all views: Gram systems and sparse coefficients, cached.

The pass renders every view once with :class:`PolynomialPathIntegrator`, tile by tile (the
tile chosen from ``memory_mb``), keeping each pixel's coefficients as sparse matrices over the
monomials that occur (2-6 % non-zero), as the two independent estimates from the two halves of
its samples: their cross product is the unbiased Gram matrix, their mean the coefficients, their
difference the per-pixel Monte Carlo noise the sandwich standard errors need
(:class:`ViewCoefficients`). From them each view's Gram system (G, b, yy)
of the cost (paper eq. 6, p = 2) is formed (:func:`~methods.symbolic.gram.weighted_system`) and
added to the sum over views, which is consumed as it goes: memory holds the sum, one view, and
its sparse coefficients, never pixels × monomials densely.

Render once, solve many: the coefficients of each view are cached on disk, keyed by everything
that affects them (scene content, view, spp, seed, N_max, parameters, guesses, selection floor,
variant, observed pixels); a cached view's Gram system is rebuilt from them by the same function,
so a cached run gives the same bits as the run that rendered.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import drjit as dr
import numpy as np
import scipy.sparse as sp

from framework.cache import Cache
from framework.errors import ConfigError
from framework.executor import SerialExecutor, TreeSum, init_worker
from framework.memory import release_freed_memory
from framework.observe import inversion_seed
from framework.render.checks import MiB, check_memory
from framework.render.mitsuba_scene import MitsubaScene
from methods.symbolic.basis import check_key_range
from methods.symbolic.gram import GramSystem, weighted_system
from methods.symbolic.integrator import integrator_class

log = logging.getLogger(__name__)
BYTES_COPIES = 3   # an event buffer lives in Dr.Jit, compacted on the device, and in numpy
MIN_TILE_PIXELS = 64


@dataclass
class ViewCoefficients:
    """A view's per-pixel coefficients, one sparse ``(pixels, len(codes))`` float64 matrix per
    channel, over the monomial ``codes`` that occur in the view (its system's codes).

    ``a``, ``b``: the two independent estimates of the coefficients from the two halves of each
    pixel's samples (each a full estimate; ``a`` holds the fraction ``split`` of the samples, 1/2
    at even spp), kept as the pass made them: the cross Gram is ½(AᵀB + BᵀA) and the estimate
    from all samples (eq. 8) is Γ = split·A + (1 - split)·B (:meth:`apply`). ``b`` is None when
    the pass had no halves (``gram=plain`` or spp < 2): ``a`` is then Γ.
    """

    a: list
    b: list | None = None
    split: float = 0.5
    codes: np.ndarray | None = None

    @property
    def n_rows(self) -> int:
        return self.a[0].shape[0]

    def apply(self, c: int, x: np.ndarray) -> np.ndarray:
        """``Γ_c x`` for channel ``c`` (x over this block's ``codes``), without forming Γ."""
        if self.b is None:
            return self.a[c] @ x
        return self.split * (self.a[c] @ x) + (1.0 - self.split) * (self.b[c] @ x)

    def blocks(self):
        """``(first row, ViewCoefficients)`` of each row block: itself, from row 0."""
        yield 0, self


class TiledCoefficients:
    """A view's coefficients as row blocks (the pass's tiles), each a :class:`ViewCoefficients`
    over the monomials of its own pixels; a block is held, or a function loading it (from the
    cache): iterating :meth:`blocks` then holds one block at a time, so a megapixel view's
    coefficients never need to fit in memory at once.

    Consumers (:func:`predicted`, :func:`~methods.symbolic.gram.weighted_system`,
    :func:`~methods.symbolic.uncertainty.score_meat`) iterate :meth:`blocks` of either class.
    """

    def __init__(self, starts, blocks: list, n_rows: int):
        self.starts = [int(s) for s in starts]
        self._blocks = list(blocks)
        self.n_rows = int(n_rows)

    def blocks(self):
        for start, block in zip(self.starts, self._blocks):
            yield start, (block() if callable(block) else block)


@dataclass
class PassResult:
    """The pass over all views: their summed Gram system, and each view's coefficients.

    ``views[name]`` is the view's :class:`TiledCoefficients`; with a cache its blocks wait on
    disk (:class:`TileLoader`): memory then stays flat in the number of views and in their size. The views' own Gram
    systems are consumed by the sum.
    """

    system: GramSystem | None                            # summed over views as a tree, in view order
    views: dict[str, object]
    render_s: float = 0.0
    from_cache: list[str] = field(default_factory=list)  # views read from the cache
    codes: np.ndarray | None = None                      # the monomials of the pass (the system's)

    def __post_init__(self):
        if self.codes is None:
            self.codes = self.system.codes

    def coefficients(self, name: str) -> TiledCoefficients:
        return self.views[name]

    def take_system(self) -> GramSystem:
        """The summed Gram system, handed over: this result keeps its ``codes`` only, so the
        solve can release the system's memory (hundreds of MB on a long street) as it restricts
        and projects it, and a refinement pass does not render with it still held."""
        system, self.system = self.system, None
        if system is None:
            raise RuntimeError("the pass's Gram system was already taken")
        return system

    def image(self, view: str, mu: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """The polynomial image of ``view`` at monomials ``mu`` (C, N) over ``codes``:
        (H, W, C) float32."""
        pixels = predicted(self.coefficients(view), mu, self.codes)
        return pixels.reshape(*shape, len(mu)).astype(np.float32)


def predicted(coeffs, mu: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """``(n, C)`` pixel values of a view's coefficients (:class:`ViewCoefficients` or
    :class:`TiledCoefficients`, Γ over each block's ``codes``) at monomials ``mu``
    (C, N) over the sorted ``codes``, a superset of the view's."""
    out = []
    for _, block in coeffs.blocks():
        at = np.searchsorted(codes, block.codes)
        out.append(np.stack([block.apply(c, mu[c][at]) for c in range(len(block.a))], axis=1))
    return np.concatenate(out)


def event_bytes_per_pixel(spp: int, max_bounces: int, n_channels: int, tail_bounces: int = 0) -> int:
    """Bytes of one pixel's event buffers in a tile.

    A pixel holds ``spp × (N_max + T + 1)`` event slots of one monomial index and ``C`` values
    (4 bytes each), held about three times (Dr.Jit buffers, their compacted copy, numpy arrays).
    The path state itself never reaches memory (the tile's paths run as one kernel): measured,
    a 256-pixel tile at 4096 spp peaked 124 MiB above the process's start, this estimate 192 MiB.
    """
    return spp * (max_bounces + tail_bounces + 1) * 4 * (1 + n_channels) * BYTES_COPIES


def tile_pixels_for(memory_mb: float, spp: int, max_bounces: int, n_channels: int, tail_bounces: int = 0) -> int:
    """Largest tile whose event buffers (:func:`event_bytes_per_pixel`) fit in ``memory_mb``
    (at least :data:`MIN_TILE_PIXELS` pixels)."""
    per_pixel = event_bytes_per_pixel(spp, max_bounces, n_channels, tail_bounces)
    return max(MIN_TILE_PIXELS, int(memory_mb * MiB // per_pixel))


def check_pass_memory(memory_mb: float, spp: int, max_bounces: int, n_channels: int, tail_bounces: int = 0,
                      *, pixels: int, tasks_here: int = 1) -> None:
    """Raise :class:`ConfigError` before the pass allocates tiles that cannot fit.

    The tile never drops below :data:`MIN_TILE_PIXELS`, so past some ``spp`` even the smallest
    tile exceeds ``memory_mb`` (``render.spp=4194304`` used to crash the process); and the
    chosen tile, ``tasks_here`` of them at once (:attr:`SerialExecutor.tasks_here`), must fit
    in the memory this machine has available (:func:`framework.render.checks.check_memory`).

    Parameters
    ----------
    memory_mb, spp, max_bounces, n_channels, tail_bounces
        As :func:`tile_pixels_for`.
    pixels : int
        Pixels of the largest view to render (a tile never holds more).
    tasks_here : int
        Views rendered at once on this machine (0: elsewhere, only ``memory_mb`` is checked).
    """
    per_pixel = event_bytes_per_pixel(spp, max_bounces, n_channels, tail_bounces)
    smallest = min(MIN_TILE_PIXELS, pixels)
    if smallest * per_pixel > memory_mb * MiB:
        need = -(-smallest * per_pixel // MiB)
        most_spp = int(memory_mb * MiB // (smallest * per_pixel // spp))
        lower = f"lower render.spp to at most {most_spp} or " if most_spp >= 1 else ""
        raise ConfigError(f"render.spp={spp} needs {need} MiB for the smallest tile of the polynomial pass "
                          f"({smallest} pixels), above method.memory_mb={memory_mb:g}: "
                          f"{lower}raise method.memory_mb to at least {need}")
    if tasks_here:
        tile = min(tile_pixels_for(memory_mb, spp, max_bounces, n_channels, tail_bounces), pixels)
        check_memory(tile * per_pixel * tasks_here, f"the polynomial pass's tiles ({tasks_here} at once)",
                     "lower method.memory_mb (smaller tiles) or render.spp")


def polynomial_pass(problem, parameters, guesses: np.ndarray, max_bounces: int, *, spp: int,
                    seed: int, prob_floor: float, memory_mb: float, cache: Cache, executor=None,
                    cross_gram: bool = True, tail_bounces: int = 0) -> PassResult:
    """Gram systems and coefficients of every view of ``problem`` (one render in total).

    Parameters
    ----------
    problem : framework.registry.Problem
    parameters : list of Parameter
        The unknowns (``D = len(parameters)``).
    guesses : numpy.ndarray
        ``(D, C)`` guess driving the kernel selection.
    max_bounces : int
        ``N_max``, the maximal degree of the polynomials.
    spp, seed, prob_floor, memory_mb
        Pass settings; view ``i`` uses the Mitsuba seed ``inversion_seed(seed, i)``.
    cross_gram : bool
        Build G from two independent half-sample estimates (unbiased by Monte Carlo noise).
    tail_bounces : int
        Reflections traced beyond N_max at the guesses (:class:`PolynomialPathIntegrator`).
    cache : Cache
        Each view's tiles of coefficients are written to it as they are rendered (by the worker
        when it runs on this machine, else by this process), then the view's index by this
        process; cached views are read back here.
    executor : framework.executor.SerialExecutor or DaskExecutor, optional
        Where views are rendered (default: this process); their results arrive one at a time,
        are cached at once and summed as a tree (:class:`framework.executor.TreeSum`) in the same
        order for both executors, so Dask and serial runs give the same estimates.

    Returns
    -------
    PassResult
        Its ``system`` is over the monomials that occur in some view (``system.codes``).
    """
    check_key_range(len(parameters), max_bounces)
    executor = executor or SerialExecutor()
    C = problem.n_channels
    views, cached, todo = {}, [], []
    total = TreeSum()
    for i, cam in enumerate(problem.cameras):
        key = _key(problem, cam, parameters, guesses, spp, seed, prob_floor, max_bounces, view=i, cross_gram=cross_gram,
                   tail_bounces=tail_bounces)
        hit = _cached_view(cache, key, _pixels(problem, cam), C)
        if hit is None:
            todo.append((i, cam, key))
            continue
        system, views[cam.name] = hit
        total.add(system)
        cached.append(cam.name)
        del system, hit
        release_freed_memory()
    t0 = time.perf_counter()
    if todo:
        check_pass_memory(memory_mb, spp, max_bounces, C, tail_bounces, tasks_here=executor.tasks_here,
                          pixels=max(cam.width * cam.height for _, cam, _ in todo))
        tile = tile_pixels_for(memory_mb, spp, max_bounces, C, tail_bounces)
        # workers on this machine store their tiles in the cache folder themselves; those of a
        # remote scheduler cannot reach it and send them back (tasks_here 0)
        worker_cache = cache.dir if executor.tasks_here else None
        tasks = [view_task(problem, parameters, guesses, max_bounces, i, spp=spp, seed=seed, prob_floor=prob_floor,
                           tile_pixels=tile, cross_gram=cross_gram, tail_bounces=tail_bounces,
                           cache_dir=worker_cache, key=key)
                 for i, _, key in todo]
        variant = problem.settings.variant
        results = executor.imap(render_view_task, tasks, variant=variant, threads=executor.threads_per_worker)
        for (i, cam, key), (system, coeffs) in zip(todo, results):
            total.add(system)                     # consumed: the sum may reuse its memory
            if cache.dir is not None:             # the tiles are stored (by the worker); then the index
                if worker_cache is None:
                    coeffs = TiledCoefficients(coeffs.starts, [_store_tile(cache, key, k, block, C)
                                                               for k, (_, block) in enumerate(coeffs.blocks())],
                                               coeffs.n_rows)
                cache.store("polynomial_pass", key, {"starts": np.asarray(coeffs.starts, np.int64),
                                                     "n_rows": np.array(coeffs.n_rows)})
            views[cam.name] = coeffs
            del system, coeffs
            release_freed_memory()                # the view's buffers and Gram products
    render_s = time.perf_counter() - t0
    ordered = {c.name: views[c.name] for c in problem.cameras}
    return PassResult(total.total(GramSystem.zeros(np.zeros(1, np.int64), C)), ordered, render_s, cached)


def view_task(problem, parameters, guesses, max_bounces: int, i: int, *, spp: int, seed: int, prob_floor: float,
              tile_pixels: int, cross_gram: bool = True, tail_bounces: int = 0, cache_dir=None,
              key: dict | None = None) -> dict:
    """Everything a worker needs to render view ``i``: plain picklable data (numpy Scene model).
    With ``cache_dir`` the worker stores each tile's coefficients there under ``key`` (the view's
    cache key) as it goes, and keeps none of them."""
    cam = problem.cameras[i]
    return {"scene": problem.scene, "cameras": list(problem.cameras), "view": int(i),
            "parameters": list(parameters), "guesses": np.asarray(guesses, float),
            "n_params": len(parameters), "max_bounces": int(max_bounces), "spp": int(spp),
            "seed": inversion_seed(seed, i), "prob_floor": float(prob_floor), "tile_pixels": int(tile_pixels),
            "observed": np.asarray(problem.observed[cam.name]), "cross_gram": bool(cross_gram),
            "tail_bounces": int(tail_bounces), "cache_dir": None if cache_dir is None else str(cache_dir),
            "key": key}


_WORKER_STATE: dict = {}    # per process: the last (MitsubaScene, integrator), reused across views


def render_view_task(task: dict, *, variant: str, threads: int | None = None
                     ) -> tuple[GramSystem, TiledCoefficients]:
    """Render one view of a :func:`view_task` in this process (driver or Dask worker).

    Selects ``variant``, caps Dr.Jit at ``threads`` threads, builds (or reuses) the Mitsuba
    scene and the polynomial integrator, and returns the view's Gram system and coefficients
    (their blocks :class:`TileLoader` s when the task stores them in its cache folder).
    """
    init_worker(variant, threads)
    ms, integrator = _scene_and_integrator(task, variant)
    cam = task["cameras"][task["view"]]
    store = None
    if task.get("cache_dir") is not None:
        store = _TileWriter(Cache(task["cache_dir"]), task["key"], task["observed"].shape[-1])
    try:
        return _render_view(integrator, ms, task["view"], cam, task["observed"], task["spp"], task["seed"],
                            cross=task.get("cross_gram", True), store=store)
    finally:
        if store is not None:
            store.close()          # every tile on disk before the view is reported done
        # Dr.Jit keeps freed buffers for reuse: the sum of the Gram systems and the solve that
        # follow would sit on a view's tile buffers (measured: flushing here took a 70-material
        # street's peak from 2.3 to 2.0 GB), and their sizes change with the view anyway.
        dr.flush_malloc_cache()


def _scene_and_integrator(task: dict, variant: str):
    scene, params = task["scene"], task["parameters"]
    key = (variant, scene.content_hash, scene.root, tuple(c.name for c in task["cameras"]), task["spp"],
           task["guesses"].tobytes(), task["prob_floor"], task["max_bounces"], task["tile_pixels"],
           task.get("tail_bounces", 0),
           tuple((p.segment, p.kernel) for p in params))
    if _WORKER_STATE.get("key") != key:
        _WORKER_STATE.pop("value", None)
        ms = MitsubaScene(scene, task["cameras"], spp=task["spp"])
        segment_kernels = [[(p.kernel, p.index) for p in params if p.segment == s]
                           for s in range(len(scene.segments))]
        integrator = integrator_class().create(
            ms.shape_segments, segment_kernels, len(params), task["guesses"],
            max_bounces=task["max_bounces"], prob_floor=task["prob_floor"], tile_pixels=task["tile_pixels"],
            tail_bounces=task.get("tail_bounces", 0))
        _WORKER_STATE.update(key=key, value=(ms, integrator))
    return _WORKER_STATE["value"]


def _render_view(integrator, ms, i, cam, observed, spp, seed, cross=True, store=None
                 ) -> tuple[GramSystem, TiledCoefficients]:
    """Tile by tile: each tile's sparse coefficients, and the view's Gram system from them.

    ``cross``: the samples of each pixel are split into two independent halves
    (:meth:`PolynomialPathIntegrator.coefficients_halves`, one render) whose cross product makes
    G free of Monte Carlo noise (:func:`~methods.symbolic.gram.weighted_system`); both halves
    are kept (:class:`ViewCoefficients`). ``store(k, block)``: called with each tile's
    :class:`ViewCoefficients`, which is then not kept: the result holds what it returns (a
    :class:`TileLoader`) instead.
    """
    from tqdm import tqdm
    C = observed.shape[-1]
    n_pix = cam.width * cam.height
    y = observed.reshape(n_pix, C)
    halves = cross and spp >= 2
    split = (spp // 2) / spp if halves else 0.5
    starts = list(range(0, n_pix, integrator.tile_pixels))
    system, blocks = _empty_system(C), []
    for k, start in enumerate(tqdm(starts, desc=f"polynomial pass {cam.name}", unit="tile", leave=False)):
        stop = min(n_pix, start + integrator.tile_pixels)
        tile = dict(spp=spp, seed=seed, pixel_range=(start, stop))
        if halves:
            codes, a, b, _ = integrator.coefficients_halves(ms.scene, i, **tile)
            block = ViewCoefficients(a, b, split, codes)
        else:
            codes, gamma = integrator.coefficients_sparse(ms.scene, i, **tile)
            block = ViewCoefficients(gamma, None, split, codes)
        # the Gram system from the kept coefficients, as a cached view's is rebuilt: the same bits
        system += weighted_system(block, y[start:stop], None)
        if store is not None:
            block = store(k, block)
        blocks.append(block)
    return system, TiledCoefficients(starts, blocks, n_pix)


def _empty_system(C: int) -> GramSystem:
    """No pixel yet, over the constant monomial (code 0), which every system holds."""
    return GramSystem.zeros(np.zeros(1, np.int64), C)


def _cached_view(cache: Cache, key: dict, y: np.ndarray, C: int):
    """``(GramSystem, TiledCoefficients)`` of a view whose pass the cache holds, its Gram system
    rebuilt tile by tile from the stored coefficients; None when the index or a tile is missing
    or corrupt (the view is then rendered again)."""
    index = cache.load("polynomial_pass", key)
    if index is None or "starts" not in index:
        return None
    starts, n_rows = [int(s) for s in index["starts"]], int(index["n_rows"])
    system = _empty_system(C)
    for k, (start, stop) in enumerate(zip(starts, starts[1:] + [n_rows])):
        hit = cache.load("polynomial_tile", _tile_key(key, k))
        if hit is None:
            return None
        system += weighted_system(_unpack(hit, C), y[start:stop], None)
    return system, _stored(cache, key, starts, n_rows, C)


def _stored(cache: Cache, key: dict, starts: list, n_rows: int, C: int) -> TiledCoefficients:
    """The view's coefficients as blocks loaded from the cache when iterated."""
    return TiledCoefficients(starts, [TileLoader(cache.dir, _tile_key(key, k), C) for k in range(len(starts))],
                             n_rows)


class _TileWriter:
    """``store(k, block)`` of :func:`_render_view` that writes each tile to the cache in a
    background thread while the next tile renders (measured on the 1920x1080 view: the writes
    were 7 of the pass's 70 s), one tile in flight at most; :meth:`close` waits for the last
    and raises what a write raised."""

    def __init__(self, cache: Cache, key: dict, C: int):
        from concurrent.futures import ThreadPoolExecutor
        self.cache, self.key, self.C = cache, key, int(C)
        self._pool, self._pending = ThreadPoolExecutor(1, thread_name_prefix="tile-writer"), None

    def __call__(self, k: int, block: ViewCoefficients) -> "TileLoader":
        self._wait()
        self._pending = self._pool.submit(_store_tile, self.cache, self.key, k, block, self.C)
        return _tile_loader(self.cache, self.key, k, self.C)

    def _wait(self) -> None:
        pending, self._pending = self._pending, None
        if pending is not None:
            pending.result()

    def close(self) -> None:
        try:
            self._wait()
        finally:
            self._pool.shutdown()


def _store_tile(cache: Cache, key: dict, k: int, block: ViewCoefficients, C: int) -> "TileLoader":
    """Store tile ``k`` of the view ``key``; the loader that reads it back."""
    cache.store("polynomial_tile", _tile_key(key, k), _pack(block))
    return _tile_loader(cache, key, k, C)


def _tile_loader(cache: Cache, key: dict, k: int, C: int) -> "TileLoader":
    """The loader of tile ``k`` of the view ``key`` (stored or being stored)."""
    return TileLoader(cache.dir, _tile_key(key, k), C)


def _tile_key(key: dict, k: int) -> dict:
    return {**key, "tile": int(k)}


def _key(problem, cam, parameters, guesses, spp, seed, prob_floor, max_bounces, *, view: int, cross_gram: bool,
         tail_bounces: int) -> dict:
    return {"scene": problem.scene.content_hash, "view": cam.name, "view_index": view, "spp": int(spp),
            "seed": int(seed), "max_bounces": int(max_bounces),
            "parameters": [[p.segment, p.kernel] for p in parameters],
            "guesses": np.round(np.asarray(guesses, float), 9).tolist(), "prob_floor": float(prob_floor),
            "observed": _digest(problem.observed[cam.name]),
            "variant": problem.settings.variant, "cross_gram": bool(cross_gram),
            "tail_bounces": int(tail_bounces), "version": 7}


def _pixels(problem, cam) -> np.ndarray:
    """``(pixels, C)`` observed radiance of ``cam``."""
    return np.asarray(problem.observed[cam.name]).reshape(cam.width * cam.height, -1)


def _digest(a: np.ndarray) -> str:
    import hashlib
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]


def _pack(coeffs: ViewCoefficients) -> dict[str, np.ndarray]:
    """The cache entry of a tile: its coefficients (its Gram system is rebuilt from them and the
    observed pixels, :func:`~methods.symbolic.gram.weighted_system`: a third of the bytes)."""
    out = {"codes": coeffs.codes, "split": np.array(coeffs.split)}
    for prefix, mats in (("a", coeffs.a), ("b", coeffs.b or [])):
        for c, m in enumerate(mats):
            out.update({f"{prefix}{c}_data": m.data, f"{prefix}{c}_indices": m.indices,
                        f"{prefix}{c}_indptr": m.indptr, f"{prefix}{c}_shape": np.array(m.shape)})
    return out


class TileLoader:
    """Reads a tile's :class:`ViewCoefficients` back from the cache folder when called; plain
    data, so a Dask worker that stored the tile can return it in place of the tile."""

    def __init__(self, cache_dir, key: dict, C: int):
        self.cache_dir, self.key, self.C = cache_dir, key, int(C)

    def __call__(self) -> ViewCoefficients:
        cache = Cache(self.cache_dir)
        hit = cache.load("polynomial_tile", self.key)
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
    b = mats("b") if "b0_data" in arrays else None
    return ViewCoefficients(mats("a"), b, float(arrays["split"]), codes)
