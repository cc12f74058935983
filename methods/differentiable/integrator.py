"""Path replay backpropagation whose adjoint also reaches the weights of Dirac lobes.

The estimator lives in :class:`DiracPRBMixin`; Mitsuba's Python AD integrator base
(``mi.ad.integrators.common.RBIntegrator``) is rebuilt for every variant, so :func:`integrator_class` builds
the plugin ``DiracPRBIntegrator`` from the mixin once per variant (:mod:`framework.render.plugin`)
and registers it as ``prb_dirac``.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from framework.render.plugin import plugin_class

PLUGIN = "prb_dirac"


class DiracPRBMixin:
    r"""Path replay backpropagation (``prb_dirac``) with gradients for the weights of Dirac lobes.

    Mitsuba's ``prb`` integrator (path replay backpropagation, Vicini et al. 2021) with one
    change in its adjoint pass. Primal images are the same as ``prb``'s (and ``path``'s, with
    the same ``max_depth``): unidirectional path tracing, emitter sampling with MIS, Russian
    roulette from ``rr_depth``. The derivatives of emission, of next-event estimation and of
    the BSDF at *smooth* sampled directions are ``prb``'s, term for term.

    What differs from ``prb``, and why
    ----------------------------------
    ``prb`` samples BSDFs *detached* and attaches the derivative of the sampled direction's
    throughput with ``bsdf.eval(wo)``, as the factor ``relative_grad(f(wo))`` on the radiance
    ``L`` the rest of the path carries. A Dirac lobe (a perfect mirror) has ``eval = 0``, so
    every weight of such a lobe gets **no gradient** (``prb``'s documentation: "the
    properties of ideal specular objects cannot be optimized"). Here the BSDF sample of the
    adjoint pass is drawn with AD enabled -- same random numbers, same direction, the same
    detached value for the path -- and, where the sampled component is a Dirac lobe, the
    factor is the *sample weight's* relative gradient instead::

        Lr_ind = L * select(delta, relative_grad(bsdf_weight),
                            relative_grad(bsdf.eval(wo)) * relative_grad(J))

    For a Dirac lobe the sampled direction does not depend on the lobe's weights, so with the
    lobe-selection probability held fixed the estimator's throughput at that vertex *is* the
    sample weight, and ``d weight / d θ`` is its exact derivative. For the ``kernel_sum`` BSDF
    (:mod:`framework.render.kernel_bsdf`) the weight of a mirror kernel is ``ρ_i w_i / q_i``
    with a detached selection probability ``q_i``, so ``d weight / d ρ_i = w_i / q_i``: the
    mirror weights receive unbiased gradients. Smooth samples keep ``bsdf.eval``: their
    sample weight ``f / pdf`` would also differentiate the pdf, which for a general BSDF
    (e.g. a rough conductor's roughness) is attached and would bias a detached estimator.

    Parameters (``mi.load_dict`` / ``mi.Properties``), as ``prb``
    -------------------------------------------------------------
    max_depth : int, default 6
        Longest path depth (-1: unbounded); 1 renders emitters seen directly, 2 direct light.
        The differentiable method uses ``N_max + T + 1``.
    rr_depth : int, default 5
        Depth from which Russian roulette may end paths.
    hide_emitters : bool, default false
        Hide directly visible emitters.

    Limitations
    -----------
    * A Dirac lobe's gradient is the derivative of its sample weight at fixed lobe choice: it
      is unbiased when the BSDF picks the lobe with a probability that carries no gradient
      (``kernel_sum``, a lone ``conductor``). Mitsuba's ``dielectric`` picks reflection with
      the attached Fresnel probability and returns weight 1, so its index of refraction still
      gets no gradient through the sampled lobe.
    * As ``prb``: no projective sampling (geometric parameters get biased gradients; through
      a mirror the direction's motion is not differentiated at all), surfaces only, no
      polarised variants.
    """

    @dr.syntax
    def sample(self, mode: dr.ADMode, scene: mi.Scene, sampler: mi.Sampler, ray: mi.Ray3f,
               δL, state_in, active: mi.Bool, **kwargs):
        """One path per lane in ``mode`` (primal, forward or backward); the interface of
        ``ADIntegrator.sample``: ``(L or δL, valid, aovs, state)``."""
        primal = mode == dr.ADMode.Primal
        bsdf_ctx = mi.BSDFContext()

        # --------------------- Loop state (as prb) ----------------------
        ray = mi.Ray3f(dr.detach(ray))
        depth = mi.UInt32(0)
        L = mi.Spectrum(0 if primal else state_in)       # radiance (primal) / still to come (adjoint)
        δL = mi.Spectrum(δL if δL is not None else 0)
        β = mi.Spectrum(1)
        η = mi.Float(1)
        active = mi.Bool(active)
        pi = scene.ray_intersect_preliminary(ray, coherent=True, reorder=False, active=active)

        ray_prev = mi.Ray3f(ray)
        pi_prev = dr.zeros(mi.PreliminaryIntersection3f)
        si_prev = dr.zeros(mi.SurfaceInteraction3f)
        bsdf_pdf_prev = mi.Float(1.0)
        bsdf_delta_prev = mi.Bool(True)

        if dr.hint(self.hide_emitters, mode="scalar"):
            skip_emitters = pi.is_valid() & (pi.shape.emitter() != None) & active
            si_skip = pi.compute_surface_interaction(ray, mi.RayFlags.Minimal, skip_emitters)
            pi[skip_emitters] = self.skip_area_emitters(scene, si_skip.spawn_ray(ray.d), True, skip_emitters)

        while dr.hint(active, max_iterations=self.max_depth, label=f"Dirac PRB ({mode.name})"):
            active_next = mi.Bool(active)

            # Surface interaction tracking shape derivatives (adjoint passes only)
            with dr.resume_grad(when=not primal):
                si = pi.compute_surface_interaction(ray, ray_flags=mi.RayFlags.All)
                if (not primal) & mi.Bool(depth >= 1):
                    si_prev_diff = pi_prev.compute_surface_interaction(ray_prev, ray_flags=mi.RayFlags.Minimal)
                    si_prev = dr.replace_grad(si_prev, si_prev_diff)
                    si_detached = dr.detach(si)
                    wi_global = dr.normalize(si_prev.p - si_detached.p)
                    si.wi = dr.replace_grad(si.wi, si_detached.to_local(wi_global))

            bsdf = si.bsdf(ray)

            # ---------------------- Direct emission ----------------------
            if dr.hint(self.hide_emitters, mode="scalar"):
                active_next &= ~((depth == 0) & ~si.is_valid())
            ds = mi.DirectionSample3f(scene, si=si, ref=si_prev)
            mis = _ad().mis_weight(bsdf_pdf_prev, scene.pdf_emitter_direction(si_prev, ds, ~bsdf_delta_prev))
            with dr.resume_grad(when=not primal):
                Le = β * mis * ds.emitter.eval(si, active_next)

            # ---------------------- Emitter sampling ----------------------
            active_next &= (depth + 1 < self.max_depth) & si.is_valid()
            active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
            ds, em_weight = scene.sample_emitter_direction(si, sampler.next_2d(), True, active_em)
            active_em &= ds.pdf != 0.0

            with dr.resume_grad(when=not primal):
                if dr.hint(not primal, mode="scalar"):
                    ds, em_weight = _attach_emitter_sample(scene, si, ds, em_weight, active_em)
                wo = si.to_local(ds.d)
                bsdf_value_em, bsdf_pdf_em = bsdf.eval_pdf(bsdf_ctx, si, wo, active_em)
                mis_em = dr.select(ds.delta, 1, _ad().mis_weight(ds.pdf, bsdf_pdf_em))
                Lr_dir = β * mis_em * bsdf_value_em * em_weight

            # ------- BSDF sampling: detached path, attached weight --------
            # (prb samples with AD off; the weight kept attached here is what reaches Dirac lobes)
            with dr.resume_grad(when=not primal):
                bsdf_sample, bsdf_weight_ad = bsdf.sample(bsdf_ctx, si, sampler.next_1d(), sampler.next_2d(),
                                                          active_next)
            bsdf_sample = dr.detach(bsdf_sample)
            bsdf_weight = dr.detach(bsdf_weight_ad)
            sampled_delta = mi.has_flag(bsdf_sample.sampled_type, mi.BSDFFlags.Delta)

            L = (L + Le + Lr_dir) if primal else (L - Le - Lr_dir)
            ray_next = si.spawn_ray(si.to_world(bsdf_sample.wo))
            η *= bsdf_sample.eta
            β *= bsdf_weight

            si_prev = dr.detach(si, True)
            bsdf_pdf_prev = bsdf_sample.pdf
            bsdf_delta_prev = sampled_delta

            # -------------------- Stopping criterion ---------------------
            β_max = dr.max(mi.unpolarized_spectrum(β))
            active_next &= β_max != 0
            rr_prob = dr.minimum(β_max * η ** 2, 0.95)
            rr_active = depth >= self.rr_depth
            β[rr_active] *= dr.rcp(rr_prob)
            rr_continue = sampler.next_1d() < rr_prob
            active_next &= ~rr_active | rr_continue

            pi_next = scene.ray_intersect_preliminary(ray_next, coherent=False, reorder=False, active=active_next)

            # ------------------ Differential phase only ------------------
            if dr.hint(not primal, mode="scalar"):
                si_next = pi_next.compute_surface_interaction(ray_next, ray_flags=mi.RayFlags.Minimal,
                                                              active=active_next)
                with dr.resume_grad():
                    J = _ad().solid_angle_to_area_jacobian(si.p, si_next.p, si_next.n,
                                                           active_next & si_next.is_valid())
                    wo_world = dr.replace_grad(ray_next.d, dr.select(si_next.is_valid(),
                                                                     dr.normalize(si_next.p - si.p), ray_next.d))
                    wo = si.to_local(wo_world)
                    # 'L' holds the radiance the rest of the path brings, detached: attach the
                    # derivative of this vertex's throughput -- prb's BSDF value at a smooth
                    # sample, the sample weight at a Dirac one (eval is 0 there).
                    bsdf_val = bsdf.eval(bsdf_ctx, si, wo, active_next & ~sampled_delta)
                    Lr_ind = L * dr.select(sampled_delta, dr.relative_grad(bsdf_weight_ad),
                                           dr.relative_grad(bsdf_val) * dr.relative_grad(J))
                    Lo = Le + Lr_dir + Lr_ind

                    if dr.hint(dr.flag(dr.JitFlag.VCallRecord) and not dr.grad_enabled(Lo), mode="scalar"):
                        raise RuntimeError(
                            "prb_dirac: the differential phase's contribution is not attached to the "
                            "AD graph (no scene parameter has gradients enabled?)")
                    if dr.hint(mode == dr.ADMode.Backward, mode="scalar"):
                        dr.backward_from(δL * Lo)
                    else:
                        δL += dr.forward_to(Lo)

            reorder_hint = dr.reinterpret_array(mi.UInt32, pi_next.shape)
            reorder_hint = (reorder_hint << 1) | dr.select(active_next, 1, 0)
            depth = dr.reorder_threads(reorder_hint, 16, depth)

            depth[si.is_valid()] += 1
            active = active_next
            pi_prev = pi
            pi = pi_next
            ray_prev = ray
            ray = ray_next

        return (L if primal else δL, depth != 0, [], L)


def _ad():
    """Mitsuba's AD integrator module of the current variant (``mitsuba.ad`` is re-imported by
    every ``mi.set_variant``): the base class and prb's helpers."""
    return mi.ad.integrators.common


def _attach_emitter_sample(scene, si, ds, em_weight, active_em):
    """prb's re-attachment of a detached emitter sample: ``(ds, em_weight)`` carrying the
    derivatives of the emitter's radiance and of the moving points (textured area lights,
    the solid-angle-to-area Jacobian)."""
    is_surface = mi.has_flag(ds.emitter.flags(), mi.EmitterFlags.Surface)
    is_infinite = mi.has_flag(ds.emitter.flags(), mi.EmitterFlags.Infinite)
    is_spatially_varying = mi.has_flag(ds.emitter.flags(), mi.EmitterFlags.SpatiallyVarying)
    textured_area_em = active_em & is_surface & is_spatially_varying
    ray_em = si.spawn_ray_to(ds.p)
    ray_em.o = dr.fma(ray_em.d, ray_em.maxt, ray_em.o)
    ray_em.maxt = dr.largest(ray_em.maxt)
    si_em = scene.ray_intersect(ray_em, textured_area_em)
    ds_diff = mi.DirectionSample3f(scene, si_em, si)
    ds_diff = dr.select(textured_area_em, ds_diff, dr.zeros(mi.DirectionSample3f))
    ds_diff.d = dr.select(textured_area_em, ds_diff.d, dr.normalize(ds.p - si.p))
    ds_diff.d = dr.select(~is_infinite, ds_diff.d, ds.d)
    ds = dr.replace_grad(ds, ds_diff)
    J = _ad().solid_angle_to_area_jacobian(si.p, dr.detach(ds.p), dr.detach(ds.n), active_em & is_surface)
    em_val_diff = scene.eval_emitter_direction(si, ds, active_em)
    inv_ds_pdf = dr.select(ds.pdf != 0, dr.rcp(ds.pdf), 0)
    em_weight = dr.replace_grad(em_weight, em_val_diff * dr.detach(inv_ds_pdf))
    return ds, em_weight * dr.relative_grad(J)


def integrator_class() -> type:
    """``DiracPRBIntegrator`` of the current variant (:class:`DiracPRBMixin` on the variant's
    ``mi.ad.integrators.common.RBIntegrator``), registered as ``prb_dirac``; built once per variant."""
    return plugin_class("DiracPRBIntegrator", DiracPRBMixin, _ad().RBIntegrator, mi.register_integrator, PLUGIN)


def integrator_dict(max_depth: int) -> dict:
    """Mitsuba dict of a ``prb_dirac`` integrator of ``max_depth`` (registering the plugin)."""
    integrator_class()
    return {"type": PLUGIN, "max_depth": int(max_depth)}


def __getattr__(name):
    # ``from methods.differentiable.integrator import DiracPRBIntegrator``: the class of the
    # variant active at that moment (PEP 562 module attribute).
    if name == "DiracPRBIntegrator":
        return integrator_class()
    raise AttributeError(name)
