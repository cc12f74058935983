"""``kernel_sum``: the exact Mitsuba BSDF of a kernel BRDF Σ_i ρ_i f_i (paper eq. 3-4).

Why not ``blendbsdf``: measured with mitsuba 3.9.1 (llvm_ad_rgb, libLLVM 19 and 23 alike), a
``conductor`` with ``material: none`` nested in a ``blendbsdf`` returns a sample weight that
mixes in the sibling ``diffuse`` reflectance (ρ_s = [0.16, 0.4, 0.9] came back as
[0.27, 0.42, 0.78]) although the same conductor alone is exact; observations rendered with it
were biased. This plugin composes the registry's unit-weight kernels instead:

* ``eval``/``pdf``: Σ over the smooth kernels of ρ_i f_i and of q_i p_i (mixture pdf);
* ``sample``: kernel i is chosen with probability q_i ∝ mean_c ρ_i (uniform if all are 0); a
  delta kernel returns ρ_i w_i / q_i, a smooth one the mixture value over the mixture pdf.

It is two-sided (scanned meshes have inconsistent winding) and exposes ``rho_<i>`` to
``mi.traverse`` (differentiable), so weights change in place and under automatic differentiation.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from framework import brdf_kernels as K
from framework.render.plugin import plugin_class


def _put(callback, name, value):
    put = getattr(callback, "put", None) or callback.put_parameter
    put(name, value, mi.ParamFlags.Differentiable)


_UNITS: dict[tuple[str, str], tuple] = {}     # (variant, kernel) -> (one-sided, two-sided)


def unit_bsdf(name: str, *, two_sided: bool = False):
    """The unit-weight BSDF of kernel ``name`` (``twosided`` around it with ``two_sided``) for the
    current variant, loaded once per process and shared by every user.

    Shared, because it has no state, loading one per segment cost 4 ms each, and a BSDF the
    polynomial pass calls directly is an instance in its kernel: one loaded anew by each run would
    make every later run of a process compile that kernel again. Both forms are loaded at the first
    call for a kernel: every virtual call on BSDFs compiles a case for each instance alive, so a
    form first loaded by a later run (the pass's two-sided one, after the first run's view check)
    changed the check's kernel in the second run of a sweep (0.16 s of compilation on the CPU).
    """
    kernel = K.get(name)
    key = (mi.variant(), kernel.name)            # canonical: glossy(0.150) is glossy(0.15)
    if key not in _UNITS:
        _UNITS[key] = (mi.load_dict(kernel.weighted_bsdf(1.0)), mi.load_dict(kernel.unit_bsdf()))
    return _UNITS[key][bool(two_sided)]


#: The reflection lobe types a kernel's flags can have, in the order they are looked for.
_LOBES = ("DeltaReflection", "GlossyReflection", "DiffuseReflection")


def _lobe_flag(unit):
    """The reflection lobe type of a unit kernel as Mitsuba flags it (``conductor``: Delta,
    ``roughconductor``: Glossy, ``diffuse``: Diffuse); every kernel has exactly one lobe."""
    for lobe in _LOBES:
        flag = getattr(mi.BSDFFlags, lobe)
        if mi.has_flag(unit.flags(), flag):
            return flag
    raise ValueError(f"kernel BSDF {unit} has no reflection lobe among {', '.join(_LOBES)}")


class KernelSumMixin:
    """The ``kernel_sum`` BSDF Σ_i ρ_i f_i (paper eq. 3-4, module docstring), written once: the
    plugin class ``KernelSumBSDF`` is these methods on the current variant's ``mi.BSDF``, built
    and registered once per variant by :func:`ensure_registered`.

    Properties: ``kernels`` (comma-separated registry names); the weights ``rho_<i>`` start at 0.
    Component ``i`` has the lobe type of kernel ``i``'s own Mitsuba BSDF (Delta, Glossy or
    Diffuse reflection), on both sides.
    """

    def __init__(self, props):
        mi.BSDF.__init__(self, props)     # no super(): see framework.render.plugin
        names = [k for k in str(props["kernels"]).split(",") if k]
        self.names = names
        self.units = [unit_bsdf(k) for k in names]
        self.delta = [K.get(k).delta for k in names]
        for i in range(len(names)):
            setattr(self, f"rho_{i}", dr.zeros(mi.UnpolarizedSpectrum))
        flags = [_lobe_flag(u) for u in self.units]     # Glossy for glossy(α): not Diffuse
        both = mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
        self.m_components = [f | both for f in flags]
        self.m_flags = mi.BSDFFlags(0)
        for f in self.m_components:
            self.m_flags = self.m_flags | f

    # -- helpers ---------------------------------------------------------------------------------
    @property
    def rho(self) -> list:
        # mi.traverse writes the attributes named in traverse(): read them afresh every time
        return [getattr(self, f"rho_{i}") for i in range(len(self.names))]

    @staticmethod
    def _front(si):
        """The interaction seen from the front side, and whether it was flipped."""
        flip = mi.Frame3f.cos_theta(si.wi) < 0
        si2 = mi.SurfaceInteraction3f(si)
        si2.wi = dr.select(flip, mi.Vector3f(si.wi.x, si.wi.y, -si.wi.z), si.wi)
        return si2, flip

    def _probs(self):
        means = [sum(dr.detach(r)[c] for c in range(len(r))) / len(r) for r in self.rho]
        total = sum(means)
        n = len(self.rho)
        return [dr.select(total > 0, m / dr.maximum(total, 1e-12), 1.0 / n) for m in means]

    def _smooth(self, ctx, si, wo, active):
        value, pdf = dr.zeros(mi.UnpolarizedSpectrum), mi.Float(0)
        for unit, d, rho, q in zip(self.units, self.delta, self.rho, self._probs()):
            if d:
                continue
            v, p = unit.eval_pdf(ctx, si, wo, active)
            value += rho * mi.unpolarized_spectrum(v)
            pdf += q * p
        return value, pdf

    # -- BSDF interface --------------------------------------------------------------------------
    def sample(self, ctx, si, sample1, sample2, active=True):
        si2, flip = self._front(si)
        q = self._probs()
        bs, weight = dr.zeros(mi.BSDFSample3f), dr.zeros(mi.Spectrum)
        lo = mi.Float(0)
        for i, (unit, d, rho) in enumerate(zip(self.units, self.delta, self.rho)):
            hi = lo + q[i] if i < len(q) - 1 else mi.Float(1.0 + 1e-6)
            m = active & (sample1 >= lo) & (sample1 < hi)
            u1 = dr.clip((sample1 - lo) / dr.maximum(q[i], 1e-12), 0, 1)
            bsi, wi_ = unit.sample(ctx, si2, u1, sample2, m)
            if d:
                w = rho * mi.unpolarized_spectrum(wi_) / dr.maximum(q[i], 1e-12)
                bsi.pdf = bsi.pdf * q[i]
            else:
                value, pdf = self._smooth(ctx, si2, bsi.wo, m)
                w = dr.select(pdf > 0, value / dr.maximum(pdf, 1e-20), 0.0)
                bsi.pdf = pdf
            bsi.sampled_component = mi.UInt32(i)
            bs[m] = bsi
            weight[m] = mi.Spectrum(w)
            lo = hi
        bs.wo = dr.select(flip, mi.Vector3f(bs.wo.x, bs.wo.y, -bs.wo.z), bs.wo)
        return bs, weight & (active & (bs.pdf > 0))

    def eval(self, ctx, si, wo, active=True):
        return self.eval_pdf(ctx, si, wo, active)[0]

    def pdf(self, ctx, si, wo, active=True):
        return self.eval_pdf(ctx, si, wo, active)[1]

    def eval_pdf(self, ctx, si, wo, active=True):
        si2, flip = self._front(si)
        wo2 = dr.select(flip, mi.Vector3f(wo.x, wo.y, -wo.z), wo)
        value, pdf = self._smooth(ctx, si2, wo2, active)
        return mi.Spectrum(value) & active, pdf & active

    def traverse(self, callback):
        for i, rho in enumerate(self.rho):
            _put(callback, f"rho_{i}", rho)

    def parameters_changed(self, keys):
        pass

    def to_string(self):
        return f"KernelSumBSDF[kernels={self.names}]"


def ensure_registered() -> None:
    """Register ``kernel_sum`` for the current Mitsuba variant (plugins are per variant)."""
    plugin_class("KernelSumBSDF", KernelSumMixin, mi.BSDF, mi.register_bsdf, "kernel_sum")


def forward_bsdf(kernels: list[str], channels: tuple[str, ...] | None = None) -> dict:
    """Mitsuba dict of the exact kernel BRDF Σ_i ρ_i f_i of one segment (``kernel_sum`` plugin,
    this module); the weights start at 0 and are written at the :func:`weight_keys` through
    ``mi.traverse`` (:meth:`framework.render.mitsuba_scene.MitsubaScene.set_weights`)."""
    ensure_registered()
    return {"type": "kernel_sum", "kernels": ",".join(kernels)}


def weight_keys(kernels) -> list[str]:
    """The ``mi.traverse`` key of each kernel's weight ρ_i, relative to the shape's ``bsdf``."""
    return [f"rho_{i}" for i in range(len(kernels))]
