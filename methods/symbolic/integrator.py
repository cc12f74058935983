"""Polynomial path tracer: every pixel as a polynomial in the kernel weights ρ (paper eq. 7-8)."""
from __future__ import annotations

import warnings
from typing import Sequence

import drjit as dr
import mitsuba as mi
import numpy as np

from framework import kernels as kernel_registry
from framework.errors import ConfigError
from methods.symbolic.basis import MonomialBasis



def mis_weight(pdf_a, pdf_b):
    """Power heuristic ``pdf_a² / (pdf_a² + pdf_b²)`` (0 where ``pdf_a = 0``), as Mitsuba's ``path``."""
    a2 = dr.square(pdf_a)
    return dr.select(pdf_a > 0, a2 / dr.fma(pdf_b, pdf_b, a2), 0)


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


def _define_class():
    """The integrator class for the *current* Mitsuba variant (``mi.SamplingIntegrator`` and
    every Mitsuba type differ between variants, so one process can run rgb and mono scenes)."""

    class PolynomialPathIntegrator(mi.SamplingIntegrator):
        r"""Polynomial (a.k.a. "symbolic", paper section 4.2) path tracer for kernel-BRDF scenes.

        Every segment ``s`` of the scene has the kernel BRDF ``f_s = Σ_k ρ_{p_k} f_k`` (paper eq. 3-4),
        a weighted sum of parameterless *unit* kernels ``f_k`` (:mod:`framework.kernels`). A light
        path ``C`` that reflects on kernels ``k_0 .. k_{d-1}`` (parameters ``p_0 .. p_{d-1}``) carries
        ``L(ρ, C) = α ∏_i ρ_{p_i}`` (eq. 7), so each pixel is a polynomial of degree ``<= N_max``
        in ``ρ`` (eq. 8). This integrator estimates the coefficients ``γ`` of that polynomial in the
        :class:`~methods.symbolic.basis.MonomialBasis` with **one** Monte Carlo pass; any ``ρ`` can
        then be evaluated without ray tracing.

        Estimator
        ---------
        Per sample, with throughput ``β`` (starting at the sensor weight), key ``κ = 0``:

        * A camera ray that hits an emitter (area light, or ``envmap``/``constant`` on a miss) adds
          ``β·Le`` to the constant monomial (index 0).
        * At surface vertex ``i < N_max`` of segment ``s``: one kernel ``k`` of ``s`` is chosen with
          probability ``q_k`` (below); the key becomes ``κ += (p_k + 1)(D + 1)^i``.
          Next-event estimation (``scene.sample_emitter_direction``: area, ``envmap``, ``constant``,
          ``directional``...) through ``f_k`` unless ``k`` is a Dirac kernel, weighted by the power
          heuristic against the pdf of ``f_k`` (1 for delta lights); then a direction is drawn from
          ``f_k`` and ``β *= f_k·cos/pdf / q_k``. An emitter hit by that ray gets the complementary
          MIS weight (1 after a Dirac kernel). Both go to the monomial ``key_table[κ]`` of the path
          including vertex ``i`` -- exactly Mitsuba's ``path`` integrator, with the BSDF of the
          chosen kernel at unit weight in place of the segment's BSDF, and the division by ``q_k``.
        * No Russian roulette; paths stop after ``N_max`` reflections. A ray leaving the scene or
          hitting a shape of segment ``-1`` (emit-only, or a shape not configured) ends the path.
        * Tail (``tail_bounces = T > 0``, not in the paper): light reflected more than ``N_max``
          times is not dropped but linearised at the guesses. Vertices ``N_max .. N_max + T - 1``
          choose a kernel the same way but multiply the path by its guess ``ρ̂_{p}`` instead of
          joining the monomial, and their contributions go to the monomial of the path's first
          ``N_max`` vertices: a path of ``d > N_max`` reflections adds
          ``α ∏_{i<N_max} ρ_{p_i} ∏_{i>=N_max} ρ̂_{p_i}``. The polynomial is then exact at
          ``ρ = ρ̂`` for paths up to ``N_max + T`` reflections (Mitsuba ``path`` with
          ``max_depth = N_max + T + 1``) and its error elsewhere is of the order of
          ``ρ - ρ̂`` times the light beyond ``N_max`` reflections, instead of all of that light.

        Each sample has weight ``1/spp`` (box pixel filter: samples are uniform inside their pixel
        and never spread to a neighbour). Each path writes its contributions to ``N_max + T + 1``
        event slots (monomial, value per channel); a tile of ``tile_pixels`` pixels is one kernel,
        its non-empty events are compacted on the device and summed on the host into sparse
        matrices, so memory is ``tile_pixels × spp × (N_max + T + 1)`` events, never pixels × N_e.

        Kernel selection probabilities: ``q_k ∝ mean_c guess[p_k, c]``, floored so that every kernel
        keeps ``q_k >= min(prob_floor, 1/K)`` (``K`` kernels on the segment), renormalised. The
        estimate is unbiased for *any* ρ whatever the guesses; guesses near ρ reduce the variance.

        Parameters (``mi.load_dict`` / ``mi.Properties``)
        ------------------------------------------------
        max_bounces : int, default 3
            ``N_max``, number of reflections (>= 1); the polynomial has degree ``N_max``. Mitsuba's
            ``path`` with ``max_depth = N_max + 1`` estimates the same image.
        prob_floor : float, default 0.1
            Lower bound of the kernel selection probabilities, in [0, 1].
        tail_bounces : int, default 0
            ``T``, reflections traced beyond ``N_max`` with the guesses as weights (>= 0; 0: the
            paper's truncation).
        tile_pixels : int, default 4096
            Pixels per wavefront in :meth:`coefficients`.

        The scene-dependent configuration is given with :meth:`configure` (or :meth:`create`):
        the shape -> segment map, the kernels of every segment, ``D`` and the guesses.

        Outputs
        -------
        :meth:`coefficients` returns ``(n_pix, N_e, C)`` float32 coefficients ``γ`` (eq. 8), pixels in
        row-major order of the film's crop window. :meth:`sample` (what ``mi.render`` calls)
        returns the polynomial evaluated at the guesses, i.e. an ordinary image of the scene with
        ``ρ = guesses`` (a sanity check; it uses ``mi.render``'s own film and filter).

        Limitations
        -----------
        * Box reconstruction filter assumed in :meth:`coefficients` (other filters: warning, and
          samples are still kept in their own pixel). ``sample_border`` is ignored.
        * Surfaces only: no participating media, no polarisation; spectral variants untested.
        * Kernels are the registered two-sided unit BSDFs; no alpha/null (pass-through) surfaces.
        * Keys are 32-bit: ``(D + 1)^N_max`` must stay below 2^31.
        """

        def __init__(self, props: mi.Properties | None = None):
            if props is None:
                props = mi.Properties()
            mi.SamplingIntegrator.__init__(self, props)
            max_bounces = props.get("max_bounces", 3)
            prob_floor = props.get("prob_floor", 0.1)
            tail_bounces = props.get("tail_bounces", 0)
            self.tile_pixels = int(props.get("tile_pixels", 4096))
            if self.tile_pixels < 1:
                raise ConfigError(f"tile_pixels={self.tile_pixels}: must be >= 1")
            self._set_scalars(max_bounces, prob_floor, tail_bounces)
            self._configured = False
            self._shape_tables: dict[int, mi.Int32] = {}

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

        # ------------------------------------------------------------------------------------------
        @classmethod
        def create(cls, shape_segments, segment_kernels, n_params, guesses, *, max_bounces: int = 3,
                   prob_floor: float = 0.1, tile_pixels: int = 4096, tail_bounces: int = 0) -> "PolynomialPathIntegrator":
            """Build and :meth:`configure` an integrator in one call (arguments as there)."""
            props = mi.Properties("polynomial_path")
            props["max_bounces"] = int(max_bounces)
            props["prob_floor"] = float(prob_floor)
            props["tile_pixels"] = int(tile_pixels)
            props["tail_bounces"] = int(tail_bounces)
            integ = cls(props)
            integ.configure(shape_segments, segment_kernels, n_params, guesses)
            return integ

        def configure(self, shape_segments: Sequence[tuple], segment_kernels: Sequence[Sequence[tuple]],
                      n_params: int, guesses: np.ndarray) -> None:
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
            """
            D = int(n_params)
            if D < 1:
                raise ConfigError(f"n_params={n_params}: must be >= 1")
            if (D + 1) ** self.max_bounces >= 2 ** 31:
                raise ConfigError(f"(n_params+1)^max_bounces = {(D + 1) ** self.max_bounces} "
                                  "exceeds the 32-bit key range: lower max_bounces")
            C = dr.size_v(mi.Spectrum)
            g = np.asarray(guesses, dtype=float)
            if g.ndim == 1:
                g = g[:, None]
            if g.shape[0] != D:
                raise ConfigError(f"guesses has {g.shape[0]} rows, expected n_params={D}")
            g = np.broadcast_to(g, (D, C)).copy()
            n_seg = len(segment_kernels)
            if n_seg == 0:
                raise ConfigError("segment_kernels is empty: at least one segment is needed")
            for s, kl in enumerate(segment_kernels):
                if len(kl) == 0:
                    raise ConfigError(f"segment {s} has no kernel")
                for name, p in kl:
                    kernel_registry.get(name)
                    if not 0 <= int(p) < D:
                        raise ConfigError(f"segment {s}: parameter index {p} outside [0, {D - 1}]")
            self.n_params, self.n_channels = D, C
            self.guesses = g
            self.segment_kernels = [[(str(n), int(p)) for n, p in kl] for kl in segment_kernels]
            self.basis = MonomialBasis(D, self.max_bounces)

            # Unit BSDFs, one per distinct kernel type, loaded once.
            names = sorted({n for kl in self.segment_kernels for n, _ in kl})
            self._kernel_names = names
            self._unit_bsdfs = [mi.load_dict(kernel_registry.get(n).unit_bsdf()) for n in names]

            # Per segment kernel slots (padded to K_max): cdf, q, parameter, kernel type.
            K_max = max(len(kl) for kl in self.segment_kernels)
            q = selection_probabilities(g, self.segment_kernels, self.prob_floor)
            self.selection_probs = q
            cdf = np.ones((n_seg, K_max))
            prob = np.ones((n_seg, K_max))
            param = np.zeros((n_seg, K_max), np.uint32)
            ktype = np.zeros((n_seg, K_max), np.uint32)
            for s, kl in enumerate(self.segment_kernels):
                c = np.cumsum(q[s])
                c[-1] = 1.0
                cdf[s, :len(kl)] = c
                prob[s, :len(kl)] = q[s]
                for j, (n, p) in enumerate(kl):
                    param[s, j] = p
                    ktype[s, j] = names.index(n)
            self._K_max = K_max
            self._cdf = mi.Float(cdf.ravel())
            self._prob = mi.Float(prob.ravel())
            self._param = mi.UInt32(param.ravel())
            self._ktype = mi.UInt32(ktype.ravel())
            self._delta = mi.UInt32([int(kernel_registry.get(n).delta) for n in names])
            self._key_table = mi.UInt32(self.basis.key_table.astype(np.int64).clip(0).astype(np.uint32))
            self._guess_flat = mi.Float(g.ravel())          # index p*C + c

            self._shape_segment = {}
            for shape, seg in shape_segments:
                seg = int(seg)
                if not -1 <= seg < n_seg:
                    raise ConfigError(f"shape {shape.id()}: segment {seg} outside [-1, {n_seg - 1}]")
                sid = int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shape))[0])
                self._shape_segment[sid] = seg
            self._shape_tables = {}
            self._configured = True

        # ------------------------------------------------------------------------------------------
        def _segment_table(self, scene: mi.Scene) -> mi.Int32:
            """Registry id -> segment table covering every shape of ``scene`` (unlisted: -1)."""
            key = id(scene)
            if key not in self._shape_tables:
                ids = [int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(s))[0]) for s in scene.shapes()]
                n = max(ids + list(self._shape_segment) + [0]) + 1
                tab = np.full(n, -1, np.int32)
                for sid, seg in self._shape_segment.items():
                    tab[sid] = seg
                self._shape_tables = {key: mi.Int32(tab)}   # keep only the latest scene
            return self._shape_tables[key]

        def _check(self):
            if not self._configured:
                raise ConfigError("PolynomialPathIntegrator used before configure(): call "
                                  "configure(shape_segments, segment_kernels, n_params, guesses)")

        # ------------------------------------------------------------------------------------------
        @dr.syntax
        def _trace(self, scene, sampler, ray, beta, active, store=None):
            """Trace one path per lane (a Dr.Jit recorded loop over bounces, so that lanes whose
            path ended stop costing work) and return L, the radiance at ρ = guesses.

            ``store(slot, monomial, value, active)``, if given, receives every contribution (a
            Spectrum already multiplied by β, the MIS weight and 1/q): slot 0 for emitters seen
            from the camera, slot d + 1 for the contributions of path vertex d.
            """
            D, N_max = self.n_params, self.max_bounces
            seg_table = self._segment_table(scene)
            n_tab = dr.width(seg_table)
            ctx = mi.BSDFContext()
            K_max = self._K_max
            track = store is None                # the radiance at the guesses is wanted (sample())
            store = store or (lambda slot, mono, value, act: None)

            ray = mi.Ray3f(ray)
            active = mi.Bool(active)
            beta = mi.Spectrum(beta)
            rho_prod = mi.Spectrum(1.0)          # ∏ guess[p_i] along the path
            key = mi.UInt32(0)                   # Σ (p_i + 1)(D + 1)^i, see MonomialBasis.key_table
            stride = mi.UInt32(1)                # (D + 1)^depth
            depth = mi.UInt32(0)

            # ---------------------- Camera ray: directly visible emitters ---------------------
            si = scene.ray_intersect(ray, mi.RayFlags.All, coherent=True, active=active)
            Le = beta * si.emitter(scene, active).eval(si, active)
            store(mi.UInt32(0), mi.UInt32(0), Le, active)
            L = dr.select(active, Le, 0.0)

            while dr.hint(active, max_iterations=N_max + self.tail_bounces, label="Polynomial path"):
                # ------------------------- Segment and kernel choice ---------------------------
                sid = dr.reinterpret_array(mi.UInt32, si.shape)
                valid = active & si.is_valid() & (sid < n_tab)
                seg = dr.gather(mi.Int32, seg_table, dr.minimum(sid, n_tab - 1), valid)
                active = valid & (seg >= 0)
                segu = mi.UInt32(dr.maximum(seg, 0)) * K_max

                u = sampler.next_1d(active)
                slot = mi.UInt32(0)
                for j in range(1, K_max):
                    c_prev = dr.gather(mi.Float, self._cdf, segu + (j - 1), active)
                    slot += dr.select(u >= c_prev, 1, 0)
                idx = segu + slot
                q = dr.gather(mi.Float, self._prob, idx, active)
                p = dr.gather(mi.UInt32, self._param, idx, active)
                kt = dr.gather(mi.UInt32, self._ktype, idx, active)
                is_delta = dr.gather(mi.UInt32, self._delta, kt, active) != 0
                exact = depth < N_max            # joins the monomial; beyond N_max: the tail
                key = dr.select(active & exact, key + (p + 1) * stride, key)
                mono = dr.gather(mi.UInt32, self._key_table, key, active)
                inv_q = dr.select(active & (q > 0), dr.rcp(q), 0)
                w, rho_prod = self._choice_weight(p, inv_q, exact, rho_prod, active, track)

                # ---------------------------- Emitter sampling ---------------------------------
                active_em = active & ~is_delta
                ds, em_weight = scene.sample_emitter_direction(si, sampler.next_2d(active), True, active_em)
                active_em &= ds.pdf != 0
                wo = si.to_local(ds.d)
                bsdf_val, bsdf_pdf = self._kernel_eval_pdf(kt, ctx, si, wo, active_em)
                mis_em = dr.select(ds.delta, 1.0, mis_weight(ds.pdf, bsdf_pdf))
                contrib = dr.select(active_em, beta * bsdf_val * em_weight * mis_em * w, 0.0)

                # ------------------------------ BSDF sampling -----------------------------------
                bs, bsdf_weight = self._kernel_sample(kt, ctx, si, sampler.next_1d(active), sampler.next_2d(active),
                                              active)
                active &= bs.pdf > 0
                beta = dr.select(active, beta * bsdf_weight * w, 0.0)
                ray = si.spawn_ray(si.to_world(bs.wo))
                prev_si = mi.Interaction3f(si)
                prev_pdf = bs.pdf
                prev_delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)

                # ------------------ Emitter hit by the BSDF-sampled ray (MIS) -------------------
                si = scene.ray_intersect(ray, mi.RayFlags.All, coherent=False, active=active)
                emitter = si.emitter(scene, active)
                ds_hit = mi.DirectionSample3f(scene, si, prev_si)
                em_pdf = scene.pdf_emitter_direction(prev_si, ds_hit, active & ~prev_delta)
                em_pdf = dr.select(prev_delta, 0.0, em_pdf)
                mis_bsdf = mis_weight(prev_pdf, em_pdf)
                Le = emitter.eval(si, active & (prev_pdf > 0))
                contrib += dr.select(active, beta * Le * mis_bsdf, 0.0)

                # ------------------ Both contributions: monomial of this path -------------------
                store(depth + 1, mono, contrib, active | active_em)
                L = self._add_radiance(L, contrib * rho_prod, active | active_em, track)
                stride = dr.select(exact, stride * (D + 1), stride)
                depth += 1
                active &= depth < N_max + self.tail_bounces
            return L

        # The chosen kernel is called directly, one masked call per kernel type: a vectorised call
        # through a BSDFPtr array would trace every BSDF in Mitsuba's registry (the scene's own
        # Python kernel sums included) into the kernel.
        def _kernel_eval_pdf(self, kt, ctx, si, wo, active):
            val, pdf = mi.Spectrum(0.0), mi.Float(0.0)
            for t, bsdf in enumerate(self._unit_bsdfs):
                on = active & (kt == t)
                v, q = bsdf.eval_pdf(ctx, si, wo, on)
                val, pdf = dr.select(on, v, val), dr.select(on, q, pdf)
            return val, pdf

        def _kernel_sample(self, kt, ctx, si, u1, u2, active):
            bs, weight = dr.zeros(mi.BSDFSample3f), mi.Spectrum(0.0)
            for t, bsdf in enumerate(self._unit_bsdfs):
                on = active & (kt == t)
                b, w = bsdf.sample(ctx, si, u1, u2, on)
                bs, weight = dr.select(on, b, bs), dr.select(on, w, weight)
            return bs, weight

        def _choice_weight(self, p, inv_q, exact, rho_prod, active, track: bool):
            """Factor of β for the chosen kernel (1/q; beyond N_max also its guess ρ̂_p) and the
            product of the guesses along the path (kept only when ``track``: it only serves the
            radiance at the guesses). Plain Python branches: outside the recorded loop's syntax."""
            if not track and self.tail_bounces == 0:
                return mi.Spectrum(inv_q), rho_prod
            rho_hat = self._guess(p, active)
            w = dr.select(exact, mi.Spectrum(inv_q), rho_hat * inv_q)
            return w, (dr.select(exact, rho_prod * rho_hat, rho_prod) if track else rho_prod)

        @staticmethod
        def _add_radiance(L, value, mask, track: bool):
            return L + dr.select(mask, value, 0.0) if track else L

        def _guess(self, p, active):
            """The guesses of parameter ``p``, one per channel (for the radiance at the guesses)."""
            g = mi.Spectrum(0.0)
            for c in range(self.n_channels):
                g[c] = dr.gather(mi.Float, self._guess_flat, p * self.n_channels + c, active)
            return g

        # ------------------------------------------------------------------------------------------
        def sample(self, scene, sampler, ray, medium=None, active=True):
            """Radiance of ``ray`` with ρ = guesses: the polynomial evaluated at the guesses."""
            self._check()
            L = self._trace(scene, sampler, mi.Ray3f(ray), mi.Spectrum(1.0), mi.Bool(active))
            return L, mi.Bool(active), []

        def aov_names(self):
            return []

        def to_string(self):
            return (f"PolynomialPathIntegrator[max_bounces={self.max_bounces}, "
                    f"tail_bounces={self.tail_bounces}, prob_floor={self.prob_floor}]")

        # ------------------------------------------------------------------------------------------
        def coefficients(self, scene: mi.Scene, sensor=0, *, spp: int, seed: int = 0,
                         pixel_range: tuple[int, int] | None = None) -> np.ndarray:
            """Dense ``(stop - start, N_e, C)`` float32 coefficients ``γ`` (eq. 8) of one view's pixels.

            Same arguments as :meth:`coefficients_sparse`, whose result this densifies (for tests and
            small images; the inversion keeps the sparse form).
            """
            mats = self.coefficients_sparse(scene, sensor, spp=spp, seed=seed, pixel_range=pixel_range)
            return np.stack([m.toarray() for m in mats], axis=-1).astype(np.float32)

        def coefficients_sparse(self, scene: mi.Scene, sensor=0, *, spp: int, seed: int = 0,
                                pixel_range: tuple[int, int] | None = None) -> list:
            """Polynomial coefficients ``γ`` (eq. 8) of the pixels of one view, one sparse matrix per channel.

            Parameters
            ----------
            scene : mi.Scene
                The scene whose shapes were given to :meth:`configure`.
            sensor : int or mi.Sensor
                Sensor (index into ``scene.sensors()`` or the sensor itself).
            spp : int
                Samples per pixel (>= 1).
            seed : int
                Sampler seed; tiles after the first derive their own seed from it.
            pixel_range : (int, int), optional
                Pixels ``[start, stop)`` in row-major order of the film's crop window; default all.

            Returns
            -------
            list of scipy.sparse.csr_matrix
                ``C`` matrices of shape ``(stop - start, N_e)``, float64, canonical (sorted indices,
                no duplicates).
            """
            return self._tiled(scene, sensor, spp, seed, pixel_range, halves=False)[0]

        def coefficients_halves(self, scene: mi.Scene, sensor=0, *, spp: int, seed: int = 0,
                                pixel_range: tuple[int, int] | None = None) -> tuple[list, list, list]:
            """``(A, B, Γ)``: two independent estimates of the coefficients and their mean, from one render.

            ``A`` uses the samples ``0 .. spp//2 - 1`` of every pixel, ``B`` the others, ``Γ`` all
            of them (``Γ = (spp//2 · A + (spp - spp//2) · B) / spp``; the lanes are laid out in two
            sample blocks, so Γ is not :meth:`coefficients_sparse`'s result at the same seed, only
            an estimate of the same coefficients). The sampler is ``independent``, so ``A`` and ``B`` are independent and
            ``E[AᵀB] = E[A]ᵀE[B]`` (:meth:`GramSystem.accumulate_sparse`). Arguments as
            :meth:`coefficients_sparse`, with ``spp >= 2``.
            """
            if int(spp) < 2:
                raise ConfigError(f"spp={spp}: two independent halves need spp >= 2")
            return self._tiled(scene, sensor, spp, seed, pixel_range, halves=True)

        def _tiled(self, scene, sensor, spp, seed, pixel_range, halves: bool) -> tuple:
            """Checks, then the tiles of ``tile_pixels`` pixels stacked: ``(Γ,)`` or ``(A, B, Γ)``."""
            import scipy.sparse as sp
            self._check()
            if isinstance(sensor, int):
                sensor = scene.sensors()[sensor]
            if int(spp) < 1:
                raise ConfigError(f"spp={spp}: must be >= 1")
            spp = int(spp)
            film = sensor.film()
            if not film.rfilter().is_box_filter():
                warnings.warn("coefficients() assumes a box pixel filter; the film's filter is "
                              f"{film.rfilter().class_().name()} (samples stay in their pixel)")
            W, H = (int(v) for v in film.crop_size())
            n_pix = W * H
            start, stop = (0, n_pix) if pixel_range is None else (int(pixel_range[0]), int(pixel_range[1]))
            if not 0 <= start <= stop <= n_pix:
                raise ConfigError(f"pixel_range=({start}, {stop}) outside [0, {n_pix}]")
            tiles = [self._tile_matrices(scene, sensor, spp, seed, t0, min(stop, t0 + self.tile_pixels), halves)
                     for t0 in range(start, stop, self.tile_pixels)]
            n_out, C = (3 if halves else 1), self.n_channels
            if not tiles:
                return tuple([sp.csr_matrix((0, self.basis.size)) for _ in range(C)] for _ in range(n_out))
            if len(tiles) == 1:
                return tiles[0]
            return tuple([sp.vstack([t[k][c] for t in tiles], format="csr") for c in range(C)]
                         for k in range(n_out))

        def _tile_matrices(self, scene, sensor, spp, seed, start, stop, halves: bool) -> tuple:
            """The events of one tile as sparse matrices: ``(Γ,)``, or ``(A, B, Γ)`` with ``halves``."""
            shape = (stop - start, self.basis.size)
            half = spp // 2 if halves else spp
            (rows, cols, vals), first_b = self._tile_events(scene, sensor, spp, seed, start, stop, half)
            if not halves:
                return (_csr(rows, cols, vals, shape),)
            in_a, in_b = slice(0, first_b), slice(first_b, len(rows))
            A = _csr(rows[in_a], cols[in_a], [v[in_a] for v in vals], shape, weight=spp / half)
            B = _csr(rows[in_b], cols[in_b], [v[in_b] for v in vals], shape, weight=spp / (spp - half))
            wa, wb = half / spp, (spp - half) / spp
            return A, B, [(a + b) * 0.5 if wa == wb else a * wa + b * wb for a, b in zip(A, B)]

        def _tile_events(self, scene, sensor, spp, seed, start, stop, split):
            """Trace one tile; every contribution is an event (pixel, monomial, value), summed later
            into sparse matrices: no dense pixels x N_e buffer (coefficients are ~1-3 % non-zero).

            Lanes come in two blocks: samples ``0 .. split - 1`` of every pixel, then the others
            (``split = spp``: one block). Returns ``((rows, cols, vals), first_b)``: the events in
            lane order (tile pixel, non-decreasing within a block, int32; monomial index, int32;
            ``C`` float32 arrays of values divided by ``spp``) and the index of the first event of
            the second block.
            """
            C = self.n_channels
            n = stop - start
            if n * spp >= 2 ** 32:
                raise ConfigError(f"tile of {n} pixels x {spp} spp too large for 32-bit indices: lower tile_pixels")
            film = sensor.film()
            W = int(film.crop_size()[0])
            crop_size = mi.ScalarVector2f(film.crop_size())
            crop_offset = mi.ScalarVector2f(film.crop_offset())

            sampler = sensor.sampler().clone()
            sampler.set_sample_count(spp)
            sampler.set_samples_per_wavefront(spp)
            sampler.seed(_tile_seed(seed, start), n * spp)

            # -------- Camera rays (as ADIntegrator.sample_rays, box filter, no border) -----------
            idx = dr.arange(mi.UInt32, n * spp)
            pix = self._lane_pixel(idx, n, spp, split) + dr.opaque(mi.UInt32, start)
            pos = mi.Vector2i()
            pos.y = mi.Int32(pix // dr.opaque(mi.UInt32, W))
            pos.x = mi.Int32(pix) - pos.y * dr.opaque(mi.Int32, W)
            pos += mi.Vector2i(film.crop_offset())
            pos_f = mi.Vector2f(pos) + sampler.next_2d()
            scale = dr.rcp(crop_size)
            offset = -crop_offset * scale
            pos_adjusted = dr.fma(pos_f, scale, offset)
            aperture = sampler.next_2d() if sensor.needs_aperture_sample() else mi.Point2f(0.5)
            time = sensor.shutter_open()
            if sensor.shutter_open_time() > 0:
                time += sampler.next_1d() * sensor.shutter_open_time()
            wavelength_sample = sampler.next_1d() if mi.is_spectral else 0.0
            ray, weight = sensor.sample_ray_differential(time=time, sample1=wavelength_sample,
                                                         sample2=pos_adjusted, sample3=aperture)

            # -------- Events: slot k of lane l holds its path's k-th (monomial, value) -------------
            lanes, slots = n * spp, self.max_bounces + self.tail_bounces + 1
            ev_mono = dr.full(mi.UInt32, _EMPTY, lanes * slots)     # slots no contribution reached
            ev_val = [dr.zeros(mi.Float, lanes * slots) for _ in range(C)]
            lane_base = dr.arange(mi.UInt32, lanes) * slots

            def store(slot, mono, value, act):
                at = lane_base + slot
                dr.scatter(ev_mono, mono, at, act)
                for c in range(C):
                    dr.scatter(ev_val[c], value[c], at, act)

            beta = mi.Spectrum(weight) * dr.opaque(mi.Float, 1.0 / spp)
            self._trace(scene, sampler, mi.Ray3f(ray), beta, mi.Bool(True), store)
            dr.eval(ev_mono, ev_val)                                   # one kernel for the tile

            # -------- Compaction on the device: most slots are empty or zero (occluded NEE) ---------
            nonzero = ev_val[0] != 0
            for c in range(1, C):
                nonzero |= ev_val[c] != 0
            keep = (ev_mono != _EMPTY) & nonzero
            at = dr.compress(keep)
            rows = self._lane_pixel(at // dr.opaque(mi.UInt32, slots), n, spp, split).numpy().view(np.int32)
            cols = dr.gather(mi.UInt32, ev_mono, at).numpy().view(np.int32)
            vals = [dr.gather(mi.Float, v, at).numpy() for v in ev_val]
            first_b = int(np.searchsorted(at.numpy(), n * split * slots))
            return (rows, cols, vals), first_b

        @staticmethod
        def _lane_pixel(lane, n: int, spp: int, split: int):
            """Tile pixel of each lane: ``n × split`` lanes (``split`` samples per pixel), then
            ``n × (spp - split)`` lanes."""
            if split == spp:
                return lane // dr.opaque(mi.UInt32, spp)
            first = dr.opaque(mi.UInt32, n * split)
            in_b = lane >= first
            return dr.select(in_b, (lane - dr.select(in_b, first, 0)) // dr.opaque(mi.UInt32, spp - split),
                             lane // dr.opaque(mi.UInt32, split))

    return PolynomialPathIntegrator


_EMPTY = 0xFFFFFFFF   # monomial index of an event slot that received no contribution


def _csr(rows, cols, vals, shape, weight: float = 1.0) -> list:
    """Canonical ``csr_matrix`` (sorted indices, duplicates summed, times ``weight``), one per
    entry of ``vals`` (channels), from events whose ``rows`` are non-decreasing.

    The channels share their sparsity, so the within-row sort runs once: scipy sorts the event
    numbers as data along with the columns, which gives the permutation for every channel.
    """
    import scipy.sparse as sp
    n, m = shape[0], len(cols)
    if m == 0:
        return [sp.csr_matrix(shape) for _ in vals]
    indptr = np.searchsorted(rows, np.arange(n + 1))
    perm = sp.csr_matrix((np.arange(m, dtype=np.float64), cols, indptr), shape=shape)
    perm.sort_indices()
    order, cols = perm.data.astype(np.intp), perm.indices
    first = np.empty(m, bool)                  # first event of each (row, column)
    first[0] = True
    first[1:] = (cols[1:] != cols[:-1]) | (rows[1:] != rows[:-1])
    starts = np.flatnonzero(first)
    indptr = np.searchsorted(rows[starts], np.arange(n + 1))
    out = []
    for v in vals:
        data = np.add.reduceat(v[order], starts, dtype=np.float64)
        if weight != 1.0:
            data *= weight
        mat = sp.csr_matrix((data, cols[starts], indptr), shape=shape)
        mat.has_canonical_format = True
        out.append(mat)
    return out


def _tile_seed(seed: int, start: int) -> int:
    """Seed of the tile starting at pixel ``start``: ``seed`` itself for the first tile."""
    if start == 0:
        return int(seed) & 0xFFFFFFFF
    x = (int(seed) * 0x9E3779B97F4A7C15 + int(start) * 0xBF58476D1CE4E5B9 + 1) & (2 ** 64 - 1)
    x ^= x >> 31
    x = (x * 0x94D049BB133111EB) & (2 ** 64 - 1)
    x ^= x >> 29
    return x & 0xFFFFFFFF


_CLASSES: dict[str, type] = {}


def integrator_class() -> type:
    """``PolynomialPathIntegrator`` of the current variant, registered as ``polynomial_path``."""
    variant = mi.variant()
    if variant not in _CLASSES:
        cls = _define_class()
        mi.register_integrator("polynomial_path", lambda props: cls(props))
        _CLASSES[variant] = cls
    return _CLASSES[variant]


def __getattr__(name):
    # ``from methods.symbolic.integrator import PolynomialPathIntegrator`` gives the class of the
    # variant active at that moment (PEP 562 module attribute).
    if name == "PolynomialPathIntegrator":
        return integrator_class()
    raise AttributeError(name)
