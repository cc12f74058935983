"""Polynomial path tracer: every pixel as a polynomial in the kernel weights ρ (paper eq. 7-8).

The estimator lives in :class:`PolynomialPathMixin`; ``mi.SamplingIntegrator`` (like every
Mitsuba type) differs between variants, so :func:`integrator_class` builds the Mitsuba plugin
``PolynomialPathIntegrator`` from it once per variant (:mod:`framework.render.plugin`).
Its host-side tables are :class:`~methods.symbolic.trace.integrator_tables.KernelTables`, its tiling
API :class:`~methods.symbolic.trace.integrator_tiles.CoefficientTiles`; camera rays and tile seeding
are in :mod:`methods.symbolic.trace.camera_rays`, the events a path writes and their sparse assembly in
:mod:`methods.symbolic.trace.events`.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from framework.errors import ConfigError
from framework.render.plugin import plugin_class
from methods.symbolic.options import SymbolicOptions
from methods.symbolic.trace.camera_rays import mis_weight
from methods.symbolic.trace.events import event_slots
from methods.symbolic.trace.integrator_tables import KernelTables
from methods.symbolic.trace.integrator_tiles import CoefficientTiles


class PolynomialPathMixin(KernelTables, CoefficientTiles):
    r"""Polynomial (a.k.a. "symbolic", paper section 4.2) path tracer for kernel-BRDF scenes.

    Every segment ``s`` of the scene has the kernel BRDF ``f_s = Σ_k ρ_{p_k} f_k`` (paper eq. 3-4),
    a weighted sum of parameterless *unit* kernels ``f_k`` (:mod:`framework.brdf_kernels`). A light
    path ``C`` that reflects on kernels ``k_0 .. k_{d-1}`` (parameters ``p_0 .. p_{d-1}``) carries
    ``L(ρ, C) = α ∏_i ρ_{p_i}`` (eq. 7), so each pixel is a polynomial of degree ``<= N_max``
    in ``ρ`` (eq. 8). This integrator estimates the coefficients ``γ`` of that polynomial over
    the monomials that occur (:class:`~methods.symbolic.system.basis.MonomialBasis`) with **one**
    Monte Carlo pass; any ``ρ`` can
    then be evaluated without ray tracing, and the cost (eq. 6) becomes a quadratic form in the
    monomials (:class:`~methods.symbolic.system.gram.GramSystem`).

    The Mitsuba plugin is ``PolynomialPathIntegrator``, registered as ``polynomial_path``: these
    methods on the current variant's ``mi.SamplingIntegrator`` (:func:`integrator_class`).

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
      MIS weight (1 after a Dirac kernel). Both go to the event column ``κ``, the ordered key
      of the path including vertex ``i`` (the host maps it to its monomial's multiset code) -- exactly Mitsuba's ``path`` integrator, with the BSDF of the
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

    * Unknown emitter scales (``emitter_groups`` of :meth:`configure`, not in the paper): the
      light is linear in each emitter's scale ``s_g``, so the contributions of an emitter of group
      ``g >= 1`` (seen from the camera, reached by next-event estimation or hit) go to key
      ``κ + g (D + 1)^N_max``, each vertex's two contributions in their own slots; the host
      appends the digit of ``s_g`` to the monomial
      (:func:`~methods.symbolic.trace.monomial_codes.emitter_columns`):
      a polynomial of degree ``N_max + 1`` over ``(ρ, s)``, exact in ``s``. Several
      environments (say sunsky skies of turbidity 2, 4 and 6 whose non-negative combination
      stands for a sky of unknown turbidity) are one environment to Mitsuba, their sum, which
      next-event estimation samples; each contribution of that sum is split among the parts in
      proportion to their radiance in its direction (``environment_parts``), each part then a
      group of its own: ``K`` slots per contribution for ``K`` parts.

    Each sample has weight ``1/spp`` (box pixel filter: samples are uniform inside their pixel
    and never spread to a neighbour). Each path writes its contributions to ``N_max + T + 1``
    event slots (monomial, value per channel); a tile of ``tile_pixels`` pixels is one kernel,
    its events are summed per pixel and monomial on the device (:mod:`methods.symbolic.trace.pixel_sums`;
    on the host, :mod:`methods.symbolic.trace.events`, for key ranges too wide for a key table) into
    sparse matrices, so memory is ``tile_pixels × spp × (N_max + T + 1)``
    events, never pixels × N_e.

    Kernel selection probabilities
    (:func:`~methods.symbolic.trace.integrator_tables.selection_probabilities`):
    ``q_k ∝ mean_c guess[p_k, c]``, floored so that every kernel keeps
    ``q_k >= min(prob_floor, 1/K)`` (``K`` kernels on the segment), renormalised. The estimate is unbiased for *any* ρ whatever the guesses; guesses
    near ρ reduce the variance.

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
    row-major order of the film's crop window; :meth:`coefficients_sparse` the same as sparse
    matrices, :meth:`coefficients_halves` two independent half-sample estimates and their mean.
    :meth:`sample` (what ``mi.render`` calls) returns the polynomial evaluated at the guesses,
    i.e. an ordinary image of the scene with ``ρ = guesses`` (a sanity check; it uses
    ``mi.render``'s own film and filter).

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
        mi.SamplingIntegrator.__init__(self, props)     # no super(): see framework.render.plugin
        max_bounces = props.get("max_bounces", 3)
        prob_floor = props.get("prob_floor", SymbolicOptions.prob_floor)
        tail_bounces = props.get("tail_bounces", 0)
        self.tile_pixels = int(props.get("tile_pixels", 4096))
        if self.tile_pixels < 1:
            raise ConfigError(f"tile_pixels={self.tile_pixels}: must be >= 1")
        self._set_scalars(max_bounces, prob_floor, tail_bounces)
        self._configured = False
        self.n_scales = 0
        self._env_parts: list = []
        self._tables_of: tuple | None = None       # (id of a scene, its segment table, its environment)

    # -- the path loop    # -- the path loop ---------------------------------------------------------------------------
    @dr.syntax
    def _trace(self, scene, sampler, ray, β, active, store=None):
        """Trace one path per lane (a Dr.Jit recorded loop over bounces, so that lanes whose
        path ended stop costing work) and return L, the radiance at ρ = guesses.

        ``store(slot, monomial, value, active)``, if given, receives every contribution (a
        Spectrum already multiplied by β, the MIS weight and 1/q): slot 0 for emitters seen
        from the camera, slot d + 1 for the contributions of path vertex d.
        """
        D, N_max = self.n_params, self.max_bounces
        seg_table, env = self._scene_tables(scene)
        ctx = mi.BSDFContext()
        track = store is None                # the radiance at the guesses is wanted (sample())
        store = store or _no_store

        ray = mi.Ray3f(ray)
        active = mi.Bool(active)
        β = mi.Spectrum(β)
        ρ_path = mi.Spectrum(1.0)            # ∏ guess[p_i] along the path
        κ = mi.UInt32(0)                     # ordered key Σ (p_i + 1)(D + 1)^i: the event's column
        stride = mi.UInt32(1)                # (D + 1)^depth
        depth = mi.UInt32(0)

        # Camera ray: directly visible emitters, the constant monomial
        si = scene.ray_intersect(ray, mi.RayFlags.All, coherent=True, active=active)
        L = dr.select(active, β * _emitter_at(si, env, active).eval(si, active), 0.0)

        while dr.hint(active, max_iterations=N_max + self.tail_bounces, label="Polynomial path"):
            # slot 0 (the camera ray's emitter) is stored in the first iteration, not before the
            # loop: a scatter before it makes Dr.Jit launch the camera rays as a kernel of their
            # own, writing and reading back the first hit (11 % of a 256-spp pass)
            first = active & (depth == 0)
            emitter0 = _emitter_at(si, env, first)
            self._store_site(store, mi.UInt32(0), mi.UInt32(0), β * emitter0.eval(si, first), emitter0, ray.d, first)
            # One kernel k of the hit segment; up to N_max its parameter joins the monomial (eq. 7)
            active, q, p, kt, is_delta = self._choose_kernel(seg_table, si, sampler, active)
            exact = depth < N_max            # beyond N_max: the tail, weighted by the guess
            κ = dr.select(active & exact, κ + (p + 1) * stride, κ)
            inv_q = dr.select(active & (q > 0), dr.rcp(q), 0)
            w, ρ_path = self._choice_weight(p, inv_q, exact, ρ_path, active, track)

            # Emitter sampling through f_k (not through a Dirac kernel: its pdf is 0 there)
            active_em = active & ~is_delta
            ds, em_weight = scene.sample_emitter_direction(si, sampler.next_2d(active), True, active_em)
            active_em &= ds.pdf != 0
            wo = si.to_local(ds.d)
            f_val, f_pdf = self._kernel_eval_pdf(kt, ctx, si, wo, active_em)
            mis_em = dr.select(ds.delta, 1.0, mis_weight(ds.pdf, f_pdf))
            contrib_em = dr.select(active_em, β * f_val * em_weight * mis_em * w, 0.0)

            # BSDF sampling of f_k: β *= f_k cos / pdf / q_k
            bs, f_weight = self._kernel_sample(kt, ctx, si, sampler.next_1d(active), sampler.next_2d(active),
                                               active)
            active &= bs.pdf > 0
            β = dr.select(active, β * f_weight * w, 0.0)
            ray = si.spawn_ray(si.to_world(bs.wo))
            prev_si = mi.Interaction3f(si)
            prev_delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)

            # Emitter hit by the BSDF-sampled ray, with the complementary MIS weight
            si = scene.ray_intersect(ray, mi.RayFlags.All, coherent=False, active=active)
            Le, mis_bsdf, hit_emitter = _emission_hit(scene, env, si, prev_si, bs.pdf, prev_delta, active)
            contrib_hit = dr.select(active, β * Le * mis_bsdf, 0.0)

            # Both contributions belong to the monomial of the path up to this vertex
            self._store_vertex(store, depth, κ, (contrib_em, ds.emitter, ds.d, active_em),
                               (contrib_hit, hit_emitter, ray.d, active))
            L = self._add_radiance(L, (contrib_em + contrib_hit) * ρ_path, active | active_em, track)
            stride = dr.select(exact, stride * (D + 1), stride)
            depth += 1
            active &= depth < N_max + self.tail_bounces
        return L

    def _choose_kernel(self, seg_table, si, sampler, active):
        """Segment of the hit shape (a miss or segment -1 ends the path) and one of its kernels,
        drawn with probability ``q`` by inverting the segment's cdf (eq. 4 is the sum it samples).

        Returns ``(active, q, p, kt, is_delta)``: the lanes still on a path, and per lane the
        chosen kernel's probability, parameter index, kernel type and Dirac flag.
        """
        seg, valid = seg_table.lookup(dr.reinterpret_array(mi.UInt32, si.shape), active & si.is_valid())
        active = valid & (seg >= 0)
        segu = mi.UInt32(dr.maximum(seg, 0)) * self._K_max
        u = sampler.next_1d(active)
        k = mi.UInt32(0)                     # the segment's k-th kernel: k cdf values are <= u
        for j in range(1, self._K_max):
            c_prev = dr.gather(mi.Float, self._cdf, segu + (j - 1), active)
            k += dr.select(u >= c_prev, 1, 0)
        idx = segu + k
        q = dr.gather(mi.Float, self._prob, idx, active)
        p = dr.gather(mi.UInt32, self._param, idx, active)
        kt = dr.gather(mi.UInt32, self._ktype, idx, active)
        is_delta = dr.gather(mi.UInt32, self._delta, kt, active) != 0
        return active, q, p, kt, is_delta

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

    def _choice_weight(self, p, inv_q, exact, ρ_path, active, track: bool):
        """Factor of β for the chosen kernel (1/q; beyond N_max also its guess ρ̂_p) and the
        product of the guesses along the path (kept only when ``track``: it only serves the
        radiance at the guesses). Plain Python branches: outside the recorded loop's syntax."""
        if not track and self.tail_bounces == 0:
            return mi.Spectrum(inv_q), ρ_path
        ρ_hat = self._guess(p, active)
        w = dr.select(exact, mi.Spectrum(inv_q), ρ_hat * inv_q)
        return w, (dr.select(exact, ρ_path * ρ_hat, ρ_path) if track else ρ_path)

    def _emitter_key(self, κ, emitter, active):
        """``κ`` with the group of ``emitter`` above its ``N_max`` digits (unknown emitter scales);
        ``κ`` itself when every emitter is known. Plain Python branch: outside the loop's syntax."""
        if not self.n_scales:
            return κ
        return κ + self._group(emitter, active) * mi.UInt32((self.n_params + 1) ** self.max_bounces)

    def _store_vertex(self, store, depth, κ, em, hit):
        """Store vertex ``depth``'s next-event and emitter-hit contributions, each given as
        ``(value, emitter, direction, active)``: in one slot, or, with unknown emitter scales, at
        two sites (the two emitters may differ), each keyed by its emitter."""
        if not self.n_scales:
            store(depth + 1, κ, em[0] + hit[0], em[3] | hit[3])
            return
        self._store_site(store, 2 * depth + 1, κ, *em)
        self._store_site(store, 2 * depth + 2, κ, *hit)

    def _store_site(self, store, site, κ, value, emitter, d, active):
        """Store one contribution, reached along world direction ``d``, keyed by its ``emitter``.

        With several environments summed into the one Mitsuba renders (``environment_parts`` of
        :meth:`configure`), a contribution of that sum is split among its parts in proportion to
        each part's radiance along ``d`` (the ratios sum to 1: the sum is unchanged), each part
        keyed by its own group, in the site's ``K`` slots ``site·K .. site·K + K - 1``.
        Plain Python branches: outside the loop's syntax."""
        key = self._emitter_key(κ, emitter, active)
        if not self._env_parts or store is _no_store:
            store(site, key, value, active)
            return
        K = len(self._env_parts)
        on_env = active & (dr.reinterpret_array(mi.UInt32, emitter) == self._env_id)
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wi = -d
        L = [part.eval(si, on_env) for part, _ in self._env_parts]
        total = sum(L[1:], L[0])
        inv = dr.select(total > 0, dr.rcp(total), 0.0)
        top = mi.UInt32((self.n_params + 1) ** self.max_bounces)
        for k, (_, g) in enumerate(self._env_parts):
            key_k, value_k = κ + mi.UInt32(g) * top, value * L[k] * inv
            if k == 0:                       # the slot a contribution of any other emitter takes
                store(site * K, dr.select(on_env, key_k, key), dr.select(on_env, value_k, value), active)
            else:
                store(site * K + k, key_k, value_k, on_env)

    def event_slots(self) -> int:
        """Event slots of one path (:func:`~methods.symbolic.trace.events.event_slots`)."""
        return event_slots(self.max_bounces, self.tail_bounces, self.n_scales, len(self._env_parts))

    @staticmethod
    def _add_radiance(L, value, mask, track: bool):
        """``L + value`` where ``mask``, when the radiance at the guesses is tracked."""
        return L + dr.select(mask, value, 0.0) if track else L

    def _guess(self, p, active):
        """The guesses of parameter ``p``, one per channel (for the radiance at the guesses)."""
        g = mi.Spectrum(0.0)
        for c in range(self.n_channels):
            g[c] = dr.gather(mi.Float, self._guess_flat, p * self.n_channels + c, active)
        return g

    # -- mi.SamplingIntegrator interface -----------------------------------------------------------
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

def _no_store(slot, mono, value, active):
    """The ``store`` of :meth:`PolynomialPathMixin._trace` when only the radiance is wanted."""


def _emitter_at(si, environment, active):
    """The emitter a ray found at ``si``: the hit shape's area light, or on a miss ``environment``
    (an opaque pointer, or None). Mitsuba's ``si.emitter(scene)``, with the environment opaque
    (:meth:`~methods.symbolic.trace.integrator_tables.KernelTables._scene_tables` says why)."""
    emitter = si.shape.emitter()
    if environment is not None:
        emitter = dr.select(si.is_valid(), emitter, environment)
    return dr.select(active, emitter, dr.zeros(mi.EmitterPtr))


def _emission_hit(scene, environment, si, prev_si, prev_pdf, prev_delta, active):
    """``(Le, mis, emitter)``: radiance of the emitter hit at ``si`` by a ray sampled from the kernel at
    ``prev_si`` with pdf ``prev_pdf``, and its MIS weight against emitter sampling (1 after a
    Dirac kernel, which emitter sampling cannot reach), as Mitsuba's ``path``."""
    emitter = _emitter_at(si, environment, active)
    ds = mi.DirectionSample3f(scene, si, prev_si)
    ds.emitter = emitter                 # the constructor's own is si.emitter(scene): a literal
    em_pdf = scene.pdf_emitter_direction(prev_si, ds, active & ~prev_delta)
    em_pdf = dr.select(prev_delta, 0.0, em_pdf)
    mis = mis_weight(prev_pdf, em_pdf)
    return emitter.eval(si, active & (prev_pdf > 0)), mis, emitter


def integrator_class() -> type:
    """``PolynomialPathIntegrator`` of the current variant (:class:`PolynomialPathMixin` on the
    variant's ``mi.SamplingIntegrator``), registered as ``polynomial_path``; built once per variant."""
    return plugin_class("PolynomialPathIntegrator", PolynomialPathMixin, mi.SamplingIntegrator,
                        mi.register_integrator, "polynomial_path")


def __getattr__(name):
    # ``from methods.symbolic.trace.integrator import PolynomialPathIntegrator`` gives the class of the
    # variant active at that moment (PEP 562 module attribute).
    if name == "PolynomialPathIntegrator":
        return integrator_class()
    raise AttributeError(name)
