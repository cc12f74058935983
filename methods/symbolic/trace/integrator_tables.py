"""Host-side tables of the polynomial path tracer: the scalars, the segments' kernels and their
selection probabilities, the shape -> segment table (:class:`KernelTables`, a base of
:class:`~methods.symbolic.trace.integrator.PolynomialPathMixin`)."""
from __future__ import annotations

from collections.abc import Sequence
from typing import Self

import drjit as dr
import mitsuba as mi
import numpy as np

from framework import brdf_kernels as kernel_registry
from framework.errors import ConfigError
from framework.render.arrays import device_array
from framework.render.kernel_bsdf import unit_bsdf
from methods.symbolic.options import SymbolicOptions
from methods.symbolic.trace.monomial_codes import check_key_range


def selection_probabilities(guesses: np.ndarray, segment_kernels, prob_floor: float) -> list[np.ndarray]:
    """Per segment, the kernel selection probabilities ``q_k``.

    ``q_k ∝ mean_c guess[p_k, c]`` floored at ``min(prob_floor, 1/K)`` and renormalised so that
    every ``q_k >= floor`` and ``Σ_k q_k = 1`` exactly (water filling: the kernels at the floor keep
    it, the others share the rest in proportion to their guesses). All-zero guesses: uniform.
    """
    out = []
    for kernels in segment_kernels:
        K = len(kernels)
        w = np.array([max(float(np.mean(guesses[p])), 0.0) for _, p in kernels])
        floor = min(float(prob_floor), 1.0 / K)
        if w.sum() <= 0:
            out.append(np.full(K, 1.0 / K))
            continue
        fixed = np.zeros(K, bool)
        for _ in range(K):
            free_mass = 1.0 - floor * fixed.sum()
            q = np.where(fixed, floor, free_mass * w / max(w[~fixed].sum(), 1e-300))
            newly = (q < floor) & ~fixed
            if not newly.any():
                break
            fixed |= newly
        q = np.where(fixed, floor, q)
        out.append(q / q.sum())
    return out


class KernelTables:
    """The integrator's model of the scene, set on the host: :meth:`configure` (or :meth:`create`)
    takes the shapes' segments, the segments' kernels and the guesses and builds the device tables
    the path loop reads."""

    def _set_scalars(self, max_bounces, prob_floor, tail_bounces=0):
        if int(max_bounces) != max_bounces or int(max_bounces) < 1:
            raise ConfigError(f"max_bounces={max_bounces}: N_max must be an integer in [1, ∞) "
                              "(1 = direct lighting only)")
        if not (0.0 <= float(prob_floor) <= 1.0):
            raise ConfigError(f"prob_floor={prob_floor}: must be in [0, 1]")
        if int(tail_bounces) != tail_bounces or int(tail_bounces) < 0:
            raise ConfigError(f"tail_bounces={tail_bounces}: must be an integer in [0, ∞) "
                              "(0 = no light beyond max_bounces reflections)")
        self.max_bounces = int(max_bounces)
        self.prob_floor = float(prob_floor)
        self.tail_bounces = int(tail_bounces)

    @classmethod
    def create(cls, shape_segments, segment_kernels, n_params, guesses, *, max_bounces: int = 3,
               prob_floor: float = SymbolicOptions.prob_floor, tile_pixels: int = 4096, tail_bounces: int = 0,
               emitter_groups: Sequence[tuple] = (), environment=None,
               environment_parts: Sequence[tuple] = ()) -> Self:
        """Build and :meth:`configure` an integrator in one call (arguments as there)."""
        props = mi.Properties("polynomial_path")
        props["max_bounces"] = int(max_bounces)
        props["prob_floor"] = float(prob_floor)
        props["tile_pixels"] = int(tile_pixels)
        props["tail_bounces"] = int(tail_bounces)
        integ = cls(props)
        integ.configure(shape_segments, segment_kernels, n_params, guesses, emitter_groups=emitter_groups,
                        environment=environment, environment_parts=environment_parts)
        return integ

    def configure(self, shape_segments: Sequence[tuple], segment_kernels: Sequence[Sequence[tuple]],
                  n_params: int, guesses: np.ndarray, *, emitter_groups: Sequence[tuple] = (),
                  environment=None, environment_parts: Sequence[tuple] = ()) -> None:
        """Set the scene-dependent model.

        Parameters
        ----------
        shape_segments : list of (mi.Shape, int)
            Each shape with its segment index, or -1 for emit-only shapes (they absorb).
        segment_kernels : list of list of (str, int)
            Per segment, its kernels as (registered kernel name, parameter index into ρ).
        n_params : int
            ``D``, the length of ρ.
        guesses : numpy.ndarray
            ``(D, C)`` guesses of ρ, used for the kernel selection probabilities and by
            :meth:`sample`.
        emitter_groups : list of (mi.Emitter, int)
            The emitters of unknown scale, each with its group ``g >= 1`` (the ``g``-th unknown
            scale; emitters not listed are group 0, known). Their contributions are kept apart:
            the path key carries the group (:func:`~methods.symbolic.trace.monomial_codes.emitter_columns`).
        environment : mi.Emitter, optional
            The scene's environment when it is the sum of several (``environment_parts``).
        environment_parts : list of (mi.Emitter, int)
            The environments summed into ``environment``, each built outside the scene at its
            scale, with its group (``>= 0``; 0: known): a contribution of ``environment`` is split
            among them by their radiance in its direction. Ignored when no part has a group ``>= 1``.
        """
        D = int(n_params)
        if D < 1:
            raise ConfigError(f"n_params={n_params}: must be >= 1")
        parts = [(em, int(g)) for em, g in environment_parts] if any(g for _, g in environment_parts) else []
        if parts and environment is None:
            raise ConfigError("environment_parts given without environment: pass the scene's summed environment")
        self.n_scales = max([int(g) for _, g in emitter_groups] + [g for _, g in parts] + [0])
        g = self._checked_guesses(segment_kernels, D, guesses)
        self.n_params, self.n_channels = D, g.shape[1]
        self.guesses = g
        self.segment_kernels = [[(str(n), int(p)) for n, p in kl] for kl in segment_kernels]
        self._build_kernel_tables()
        self._shape_segment = _shape_ids(shape_segments, len(self.segment_kernels))
        self._tables_of = None
        self._emitter_group = _emitter_table(emitter_groups)
        self._env_parts = parts
        self._env_id = dr.opaque(mi.UInt32, _emitter_id(environment) if parts else 0)   # see _scene_tables
        self._configured = True

    def _checked_guesses(self, segment_kernels, D: int, guesses) -> np.ndarray:
        """Check the key range and the kernels; the guesses as a ``(D, C)`` array (broadcast over
        the channels)."""
        check_key_range(D, self.max_bounces, self.n_scales)
        C = dr.size_v(mi.Spectrum)
        g = np.asarray(guesses, dtype=float)
        if g.ndim == 1:
            g = g[:, None]
        if g.shape[0] != D:
            raise ConfigError(f"guesses has {g.shape[0]} rows, expected n_params={D}")
        g = np.broadcast_to(g, (D, C)).copy()
        if len(segment_kernels) == 0:
            raise ConfigError("segment_kernels is empty: at least one segment is needed")
        for s, kl in enumerate(segment_kernels):
            if len(kl) == 0:
                raise ConfigError(f"segment {s} has no kernel")
            for name, p in kl:
                kernel_registry.get(name)
                if not 0 <= int(p) < D:
                    raise ConfigError(f"segment {s}: parameter index {p} outside [0, {D - 1}]")
        return g

    def _build_kernel_tables(self) -> None:
        """Device tables of the kernel choice: per segment, ``K_max`` slots (padded) of selection
        cdf, ``q``, parameter and kernel type; the unit BSDF and Dirac flag of each kernel type;
        and the guesses (index ``p·C + c``)."""
        names = sorted({n for kl in self.segment_kernels for n, _ in kl})
        self._unit_bsdfs = [unit_bsdf(n, two_sided=True) for n in names]      # shared: see unit_bsdf
        n_seg = len(self.segment_kernels)
        K_max = max(len(kl) for kl in self.segment_kernels)
        q = selection_probabilities(self.guesses, self.segment_kernels, self.prob_floor)
        self.selection_probs = q
        cdf = np.ones((n_seg, K_max))               # padding slots are never chosen: cdf 1
        prob = np.ones((n_seg, K_max))
        param = np.zeros((n_seg, K_max), np.uint32)
        ktype = np.zeros((n_seg, K_max), np.uint32)
        for s, kl in enumerate(self.segment_kernels):
            c = np.cumsum(q[s])
            c[-1] = 1.0                                 # no gap above the last kernel from rounding
            cdf[s, :len(kl)] = c
            prob[s, :len(kl)] = q[s]
            for j, (n, p) in enumerate(kl):
                param[s, j] = p
                ktype[s, j] = names.index(n)
        self._K_max = K_max
        self._cdf = device_array(mi.Float, cdf.ravel())
        self._prob = device_array(mi.Float, prob.ravel())
        self._param = device_array(mi.UInt32, param.ravel())
        self._ktype = device_array(mi.UInt32, ktype.ravel())
        self._delta = device_array(mi.UInt32, [kernel_registry.get(n).delta for n in names])
        self._guess_flat = device_array(mi.Float, self.guesses.ravel())

    def _scene_tables(self, scene: mi.Scene) -> tuple:
        """``(segments, environment)`` of ``scene``, built once for the latest scene:

        * ``segments``: registry id -> segment of every shape of ``scene`` (unlisted: -1);
        * ``environment``: ``scene``'s environment emitter as an opaque ``mi.EmitterPtr``, or None.
          Opaque, because Mitsuba's ``si.emitter(scene)`` writes the environment's registry id into
          the kernel as a literal, and the id depends on which objects earlier runs of the process
          left alive: a later run would compile the pass again.

        Kept by ``id(scene)``, not holding ``scene``: the scene holds this integrator, and a
        reference back would keep both alive for ever (with their emitters' registry ids).
        """
        if self._tables_of is None or self._tables_of[0] != id(scene):
            ids = [_shape_id(s) for s in scene.shapes()]
            tab = np.full(max(ids + list(self._shape_segment) + [0]) + 1, -1, np.int32)
            for sid, seg in self._shape_segment.items():
                tab[sid] = seg
            env = scene.environment()
            self._tables_of = (id(scene), IdTable(mi.Int32, tab), None if env is None else dr.opaque(mi.EmitterPtr, env))
        return self._tables_of[1:]

    def _group(self, emitter, active):
        """Group of the emitter each lane's ``emitter`` pointer names (0: known, or no emitter)."""
        group, _ = self._emitter_group.lookup(dr.reinterpret_array(mi.UInt32, emitter), active)
        return group

    def _check(self):
        if not self._configured:
            raise ConfigError("PolynomialPathIntegrator used before configure(): call "
                              "configure(shape_segments, segment_kernels, n_params, guesses)")


class IdTable:
    """A table read on the device by Mitsuba registry id (of a shape or an emitter).

    Its size is opaque: registry ids depend on which objects a process holds, so a size written
    into the kernel as a literal would make a later run compile the pass again."""

    def __init__(self, kind, values: np.ndarray):
        self.kind, self.values = kind, device_array(kind, values)
        self.size = dr.opaque(mi.UInt32, len(values))

    def lookup(self, ids, active):
        """``(value, inside)``: the entry of each lane's registry id ``ids`` where ``active`` and
        the id is inside the table (elsewhere 0, and ``inside`` False)."""
        inside = active & (ids < self.size)
        return dr.gather(self.kind, self.values, dr.minimum(ids, self.size - 1), inside), inside


def _shape_id(shape) -> int:
    """Mitsuba's registry id of ``shape``: the value ``si.shape`` holds for it on the device."""
    return int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shape))[0])


def _shape_ids(shape_segments, n_seg: int) -> dict[int, int]:
    """Registry id -> segment of each configured shape, the segment checked in ``[-1, n_seg)``."""
    out = {}
    for shape, seg in shape_segments:
        seg = int(seg)
        if not -1 <= seg < n_seg:
            raise ConfigError(f"shape {shape.id()}: segment {seg} outside [-1, {n_seg - 1}]")
        out[_shape_id(shape)] = seg
    return out


def _emitter_id(emitter) -> int:
    """Mitsuba's registry id of ``emitter``: the value an ``EmitterPtr`` holds for it on the device."""
    return int(dr.reinterpret_array(mi.UInt32, mi.EmitterPtr(emitter))[0])


def _emitter_table(emitter_groups) -> IdTable:
    """Registry id -> group of the listed emitters (every other id: 0), groups checked ``>= 1``."""
    ids = {}
    for emitter, g in emitter_groups:
        if int(g) < 1:
            raise ConfigError(f"emitter {emitter.id()}: group {g} must be >= 1 (0 is every emitter not listed)")
        ids[_emitter_id(emitter)] = int(g)
    tab = np.zeros(max(ids, default=0) + 1, np.uint32)
    for eid, g in ids.items():
        tab[eid] = g
    return IdTable(mi.UInt32, tab)
