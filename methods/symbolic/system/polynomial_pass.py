"""One polynomial rendering pass over all views: Gram systems and sparse coefficients, cached.

The pass renders every view once with :class:`PolynomialPathIntegrator`, tile by tile (the
tile chosen from ``memory_mb``), keeping each pixel's coefficients as sparse matrices over the
monomials that occur (2-6 % non-zero), as the two independent estimates from the two halves of
its samples: their cross product is the unbiased Gram matrix, their mean the coefficients, their
difference the per-pixel Monte Carlo noise the sandwich standard errors need
(:class:`ViewCoefficients`). From them each view's Gram system (G, b, yy)
of the cost (paper eq. 6, p = 2) is formed (:func:`~methods.symbolic.system.view_systems.weighted_system`) and
added to the sum over views, which is consumed as it goes: memory holds the sum, one view, and
its sparse coefficients, never pixels × monomials densely.

Render once, solve many: each view's coefficients are cached on disk
(:mod:`methods.symbolic.system.pass_cache`).
"""
from __future__ import annotations

import functools
import logging
import time
from dataclasses import dataclass

import drjit as dr
import numpy as np

from framework.cache import Cache
from framework.errors import ConfigError
from framework.executor import SerialExecutor, TreeSum, init_worker
from framework.memory import release_freed_memory
from framework.observe import inversion_seed
from framework.render.checks import MiB, check_memory
from framework.render.mitsuba_scene import MitsubaScene
from framework.threads import Chain
from methods.symbolic.system.coefficients import PassResult, TiledCoefficients, ViewCoefficients
from methods.symbolic.system.emitter_groups import split_environments, unknown_emitters
from methods.symbolic.system.gram import GramSystem
from methods.symbolic.system.pass_cache import (TileWriter, cached_view, camera_key, empty_system, footprint_kernel,
                                                observed_pixels, store_tile, view_key)
from methods.symbolic.system.view_systems import weighted_system
from methods.symbolic.trace.events import event_slots
from methods.symbolic.trace.integrator import integrator_class
from methods.symbolic.trace.monomial_codes import check_key_range

log = logging.getLogger(__name__)
BYTES_COPIES = 3   # an event buffer lives in Dr.Jit, compacted on the device, and in numpy
MIN_TILE_PIXELS = 64


def event_bytes_per_pixel(spp: int, max_bounces: int, n_channels: int, tail_bounces: int = 0, *,
                          n_scales: int = 0, n_parts: int = 0) -> int:
    """Bytes of one pixel's event buffers in a tile.

    A pixel holds ``spp × (N_max + T + 1)`` event slots (``spp × (2 (N_max + T) + 1)`` with
    ``n_scales`` unknown emitter scales: a vertex's two contributions kept apart; ``n_parts`` times
    that with ``n_parts`` environments split) of one monomial index and ``C`` values
    (4 bytes each), held about three times (Dr.Jit buffers, their compacted copy, numpy arrays).
    The path state itself never reaches memory (the tile's paths run as one kernel): measured,
    a 256-pixel tile at 4096 spp peaked 124 MiB above the process's start, this estimate 192 MiB.
    """
    return spp * event_slots(max_bounces, tail_bounces, n_scales, n_parts) * 4 * (1 + n_channels) * BYTES_COPIES


def tile_pixels_for(memory_mb: float, spp: int, max_bounces: int, n_channels: int, tail_bounces: int = 0, *,
                    n_scales: int = 0, n_parts: int = 0) -> int:
    """Largest tile whose event buffers (:func:`event_bytes_per_pixel`) fit in ``memory_mb``
    (at least :data:`MIN_TILE_PIXELS` pixels)."""
    per_pixel = event_bytes_per_pixel(spp, max_bounces, n_channels, tail_bounces, n_scales=n_scales, n_parts=n_parts)
    return max(MIN_TILE_PIXELS, int(memory_mb * MiB // per_pixel))


def check_pass_memory(memory_mb: float, spp: int, max_bounces: int, n_channels: int, tail_bounces: int = 0,
                      *, pixels: int, tasks_here: int = 1, n_scales: int = 0, n_parts: int = 0) -> None:
    """Raise :class:`ConfigError` before the pass allocates tiles that cannot fit.

    The tile never drops below :data:`MIN_TILE_PIXELS`, so past some ``spp`` even the smallest
    tile exceeds ``memory_mb`` (at ``render.spp=4194304`` a 64-pixel tile needs 36 GiB); and the
    chosen tile, ``tasks_here`` of them at once (:attr:`SerialExecutor.tasks_here`), must fit
    in the memory this machine has available (:func:`framework.render.checks.check_memory`).

    Parameters
    ----------
    memory_mb, spp, max_bounces, n_channels, tail_bounces, n_scales, n_parts
        As :func:`tile_pixels_for`.
    pixels : int
        Pixels of the largest view to render (a tile never holds more).
    tasks_here : int
        Views rendered at once on this machine (0: elsewhere, only ``memory_mb`` is checked).
    """
    per_pixel = event_bytes_per_pixel(spp, max_bounces, n_channels, tail_bounces, n_scales=n_scales, n_parts=n_parts)
    smallest = min(MIN_TILE_PIXELS, pixels)
    if smallest * per_pixel > memory_mb * MiB:
        need = -(-smallest * per_pixel // MiB)
        most_spp = int(memory_mb * MiB // (smallest * per_pixel // spp))
        lower = f"lower render.spp to at most {most_spp} or " if most_spp >= 1 else ""
        raise ConfigError(f"render.spp={spp} needs {need} MiB for the smallest tile of the polynomial pass "
                          f"({smallest} pixels), above method.memory_mb={memory_mb:g}: "
                          f"{lower}raise method.memory_mb to at least {need}")
    if tasks_here:
        tile = min(tile_pixels_for(memory_mb, spp, max_bounces, n_channels, tail_bounces, n_scales=n_scales,
                                   n_parts=n_parts), pixels)
        check_memory(tile * per_pixel * tasks_here, f"the polynomial pass's tiles ({tasks_here} at once)",
                     "lower method.memory_mb (smaller tiles) or render.spp")


def polynomial_pass(problem, parameters, guesses: np.ndarray, max_bounces: int, *, spp: int,
                    seed: int, prob_floor: float, memory_mb: float, cache: Cache, executor=None,
                    cross_gram: bool = True, tail_bounces: int = 0, footprint: bool = True,
                    quarters: bool = False) -> PassResult:
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
    footprint : bool
        Render the pixels of views whose photographs were resampled from a distorted camera over
        the source pixels their interpolation weighs (:func:`footprint_kernel`); False: each
        pixel's own box.
    quarters : bool
        Also keep each half's first half of the samples (:class:`ViewCoefficients` ``a1``, ``b1``;
        ``spp`` a multiple of 4, ``cross_gram``): the solve can then be repeated at half the spp
        (``method.bias=richardson``).
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
        Its ``system`` is over the monomials that occur in some view (``system.codes``): over ρ,
        and with unknown emitter scales over ``(ρ, s)``
        (:func:`~methods.symbolic.survey.illumination.pass_basis`).
    """
    G, n_parts = len(unknown_emitters(problem.scene)), len(split_environments(problem.scene))
    check_key_range(len(parameters), max_bounces, G)
    executor = executor or SerialExecutor()
    C = problem.n_channels
    views, cached, todo = {}, [], []
    total = TreeSum()
    for i, cam in enumerate(problem.cameras):
        kernel = footprint_kernel(problem, cam) if footprint else None
        key = view_key(problem, cam, parameters, guesses, spp, seed, prob_floor, max_bounces, view=i, cross_gram=cross_gram,
                       tail_bounces=tail_bounces, footprint=kernel, quarters=quarters)
        hit = cached_view(cache, key, observed_pixels(problem, cam), C)
        if hit is None:
            todo.append((i, cam, key, kernel))
            continue
        system, views[cam.name] = hit
        total.add(system)
        cached.append(cam.name)
        del system, hit
        release_freed_memory()
    t0 = time.perf_counter()
    if todo:
        check_pass_memory(memory_mb, spp, max_bounces, C, tail_bounces, tasks_here=executor.tasks_here,
                          pixels=max(cam.width * cam.height for _, cam, _, _ in todo), n_scales=G, n_parts=n_parts)
        tile = tile_pixels_for(memory_mb, spp, max_bounces, C, tail_bounces, n_scales=G, n_parts=n_parts)
        # workers on this machine store their tiles in the cache folder themselves; those of a
        # remote scheduler cannot reach it and send them back (tasks_here 0)
        worker_cache = cache.dir if executor.tasks_here else None
        tasks = [view_task(problem, parameters, guesses, max_bounces, i, spp=spp, seed=seed, prob_floor=prob_floor,
                           tile_pixels=tile, cross_gram=cross_gram, tail_bounces=tail_bounces,
                           cache_dir=worker_cache, key=key, footprint=kernel, quarters=quarters)
                 for i, _, key, kernel in todo]
        variant = problem.settings.variant
        results = executor.imap(render_view_task, tasks, variant=variant, threads=executor.threads_per_worker)
        for (i, cam, key, _), (system, coeffs) in zip(todo, results):
            total.add(system)                     # consumed: the sum may reuse its memory
            if cache.dir is not None:             # the tiles are stored (by the worker); then the index
                if worker_cache is None:
                    coeffs = TiledCoefficients(coeffs.starts, [store_tile(cache, key, k, block, C)
                                                               for k, (_, block) in enumerate(coeffs.blocks())],
                                               coeffs.n_rows)
                cache.store("polynomial_pass", key, {"starts": np.asarray(coeffs.starts, np.int64),
                                                     "n_rows": np.array(coeffs.n_rows)})
            views[cam.name] = coeffs
            del system, coeffs
            release_freed_memory()                # the view's buffers and Gram products
    render_s = time.perf_counter() - t0
    dr.flush_malloc_cache()                       # the solve follows: the tiles' buffers are done
    ordered = {c.name: views[c.name] for c in problem.cameras}
    return PassResult(total.total(GramSystem.zeros(np.zeros(1, np.int64), C)), ordered, render_s, cached)


@dataclass(frozen=True)
class ViewTask:
    """Everything a worker needs to render one view of a pass: plain picklable data (the numpy
    Scene model, arrays, seeds), built by :func:`view_task`.

    ``cache_dir``: the worker stores each tile's coefficients there under ``key`` (the view's cache
    key) as it goes, and keeps none of them; ``footprint``: an interpolation kernel
    (:func:`footprint_kernel`), each pixel rendered over the source pixels it weighs; ``cross_gram``:
    each pixel's samples in two independent halves; ``quarters``: and each half's first half too.
    """

    scene: object
    cameras: list
    view: int
    parameters: list
    guesses: np.ndarray
    max_bounces: int
    spp: int
    seed: int
    prob_floor: float
    tile_pixels: int
    observed: np.ndarray
    cross_gram: bool
    tail_bounces: int
    cache_dir: str | None
    key: dict | None
    footprint: str | None
    quarters: bool

    @property
    def camera(self):
        return self.cameras[self.view]


def view_task(problem, parameters, guesses, max_bounces: int, i: int, *, spp: int, seed: int, prob_floor: float,
              tile_pixels: int, cross_gram: bool, tail_bounces: int, cache_dir=None,
              key: dict | None = None, footprint: str | None = None, quarters: bool = False) -> ViewTask:
    """The :class:`ViewTask` of view ``i`` of ``problem`` (its seed the view's inversion seed)."""
    cam = problem.cameras[i]
    return ViewTask(scene=problem.scene, cameras=list(problem.cameras), view=int(i), parameters=list(parameters),
                    guesses=np.asarray(guesses, float), max_bounces=int(max_bounces), spp=int(spp),
                    seed=inversion_seed(seed, i), prob_floor=float(prob_floor), tile_pixels=int(tile_pixels),
                    observed=np.asarray(problem.observed[cam.name]), cross_gram=bool(cross_gram),
                    tail_bounces=int(tail_bounces), cache_dir=None if cache_dir is None else str(cache_dir),
                    key=key, footprint=footprint, quarters=bool(quarters))


def _footprint(task: ViewTask):
    """The view's :class:`~framework.scene.undistort.Resampling` (kept per camera), or None."""
    kernel = task.footprint
    if kernel is None:
        return None
    from framework.scene.undistort import Resampling, resampling_key
    cam = task.camera
    key = resampling_key(cam, kernel)
    kept = _WORKER_STATE.setdefault("footprints", {})
    if key not in kept:
        kept.clear()                 # one camera at a time: a street's views mostly share one
        kept[key] = Resampling(source=cam.delivered(), target=cam.pinhole(), kernel=kernel)
    return kept[key]


_WORKER_STATE: dict = {}    # per process: the last (MitsubaScene, integrator), reused across views


def release_pass_scene() -> None:
    """Drop this process's kept Mitsuba scene and integrator (:func:`render_view_task` keeps the
    last for the next view with the same key), and its footprints.

    A run calls it once its passes are done. Kept into the next run of the process, the scene's
    emitters held the lowest Dr.Jit registry ids, so that run's view check (Mitsuba's ``path``,
    which writes the environment's id into its kernel as a literal) got other ids than the first
    run's and compiled its kernel again (0.16 s on the CPU, a sweep's second run); dropped, every
    run starts with the same objects alive. A scene build costs 10 ms on urban_canyon.
    """
    _WORKER_STATE.clear()


def render_view_task(task: ViewTask, *, variant: str, threads: int | None = None
                     ) -> tuple[GramSystem, TiledCoefficients]:
    """Render one view of a :func:`view_task` in this process (driver or Dask worker).

    Selects ``variant``, caps Dr.Jit at ``threads`` threads, builds (or reuses) the Mitsuba
    scene and the polynomial integrator, and returns the view's Gram system and coefficients
    (their blocks :class:`TileLoader` s when the task stores them in its cache folder).
    """
    init_worker(variant, threads)
    ms, integrator = _scene_and_integrator(task, variant)
    store = None
    if task.cache_dir is not None:
        store = TileWriter(Cache(task.cache_dir), task.key, task.observed.shape[-1])
    system = None
    try:
        system, coeffs = _render_view(integrator, ms, task.view, task.camera, task.observed, task.spp, task.seed,
                                      cross=task.cross_gram, store=store, footprint=_footprint(task),
                                      quarters=task.quarters)
        return system, coeffs
    finally:
        if store is not None:
            store.close()          # every tile on disk before the view is reported done
        if system is None or system.nbytes() >= FLUSH_SYSTEM_BYTES:
            dr.flush_malloc_cache()


# Dr.Jit keeps a view's freed tile buffers for the next view's tiles. Handing them back costs the
# next view their allocation again (page faults: 0.1 s of a 0.9 s pass at 200², 64 spp), and pays
# only where the views' Gram systems are large: the systems summed beside the buffers then set the
# peak (measured: flushing after every view took a 70-material street's peak from 2.3 to 2.0 GB;
# its views' systems are 100-600 MB). The pass flushes once more at its end, before the solve.
FLUSH_SYSTEM_BYTES = 64 * MiB


def _scene_and_integrator(task: ViewTask, variant: str):
    scene, params = task.scene, task.parameters
    # the cameras by pose too: a corrected camera (methods.symbolic.misfit.alignment) keeps its name
    key = (variant, scene.content_hash, scene.root, tuple(c.name for c in task.cameras),
           tuple(tuple(camera_key(c)) for c in task.cameras), task.spp,
           task.guesses.tobytes(), task.prob_floor, task.max_bounces, task.tile_pixels, task.tail_bounces,
           tuple((p.segment, p.kernel) for p in params))
    if _WORKER_STATE.get("key") != key:
        _WORKER_STATE.pop("value", None)
        ms = MitsubaScene(scene, task.cameras, spp=task.spp)
        segment_kernels = [[(p.kernel, p.index) for p in params if p.segment == s]
                           for s in range(len(scene.segments))]
        group = {j: g + 1 for g, j in enumerate(unknown_emitters(scene))}
        groups = [(em, group[j]) for j in group for em in ms.emitter_objects(j)]
        parts = [(em, group.get(j, 0)) for j, em in ms.environment_parts] if split_environments(scene) else []
        integrator = integrator_class().create(
            ms.shape_segments, segment_kernels, len(params), task.guesses,
            max_bounces=task.max_bounces, prob_floor=task.prob_floor, tile_pixels=task.tile_pixels,
            tail_bounces=task.tail_bounces, emitter_groups=groups, environment=ms.environment,
            environment_parts=parts)
        _WORKER_STATE.update(key=key, value=(ms, integrator))
    return _WORKER_STATE["value"]


def _render_view(integrator, ms, i, cam, observed, spp, seed, cross=True, store=None, footprint=None,
                 quarters=False) -> tuple[GramSystem, TiledCoefficients]:
    """Tile by tile: each tile's sparse coefficients, and the view's Gram system from them (each
    tile's formed in a background thread while the next tile renders, summed in the tiles' order).

    ``cross``: the samples of each pixel are split into two independent halves
    (:meth:`PolynomialPathIntegrator.coefficients_halves`, one render) whose cross product makes
    G free of Monte Carlo noise (:func:`~methods.symbolic.system.view_systems.weighted_system`); both halves
    are kept (:class:`ViewCoefficients`). ``store(k, block)``: called with each tile's
    :class:`ViewCoefficients`, which is then not kept: the result holds what it returns (a
    :class:`TileLoader`) instead. ``footprint``: the view's photographs were resampled with it
    (:func:`footprint_kernel`); its pixels integrate over their source pixels. ``quarters``:
    each half's first half of the samples is kept too (``a1``, ``b1``).
    """
    from tqdm import tqdm
    C = observed.shape[-1]
    n_pix = cam.width * cam.height
    y = observed.reshape(n_pix, C)
    halves = cross and spp >= 2
    split = (spp // 2) / spp if halves else 0.5
    starts = list(range(0, n_pix, integrator.tile_pixels))
    blocks = []
    with Chain(empty_system(C), name="tile-gram") as gram:
        for k, start in enumerate(tqdm(starts, desc=f"polynomial pass {cam.name}", unit="tile", leave=False)):
            stop = min(n_pix, start + integrator.tile_pixels)
            tile = dict(spp=spp, seed=seed, pixel_range=(start, stop), footprint=footprint)
            if halves:
                codes, a, b, _, *firsts = integrator.coefficients_halves(ms.scene, i, quarters=quarters, mean=False,
                                                                         **tile)
                block = ViewCoefficients(a, b, split, codes, *firsts)
            else:
                codes, gamma = integrator.coefficients_sparse(ms.scene, i, **tile)
                block = ViewCoefficients(gamma, None, split, codes)
            # the Gram system from the kept coefficients, as a cached view's is rebuilt: the same bits;
            # formed while the next tile renders, and summed in the tiles' order
            gram.then(functools.partial(_plus_tile, block=block, y=y[start:stop]))
            if store is not None:
                block = store(k, block)
            blocks.append(block)
        return gram.result(), TiledCoefficients(starts, blocks, n_pix)


def _plus_tile(system: GramSystem, *, block: ViewCoefficients, y: np.ndarray) -> GramSystem:
    """``system`` plus the Gram system of a tile's coefficients (in place)."""
    system += weighted_system(block, y, None)
    return system
