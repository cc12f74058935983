"""Unknown emitter scales in the symbolic fit (scene.yaml ``scale: unknown``, or a sunsky's
``sun_scale`` / ``sky_scale: unknown``).

The model
    Light is additive in its emitters: a pixel is ``Σ_e s_e L_e(ρ)`` with ``L_e`` the light that
    left emitter ``e`` as scene.yaml declares it (its nominal intensity) and ``s_e`` its scale per
    channel: 1 for a known emitter, an unknown for ``scale: unknown``. The polynomial pass keeps
    the emitter of every contribution (the integrator's path keys carry its group:
    :func:`~methods.symbolic.trace.monomial_codes.emitter_columns`), so each pixel stays a polynomial, over
    ``(ρ, s)``, of degree ``N_max + 1`` and of degree 1 in each scale: the scales are estimated
    jointly with ρ from the same pass, and their std comes from the same sandwich.

Parameters
    The ``G`` unknown scales are numbered after ρ (``D .. D + G - 1``) and before the exposure gains
    and the vignetting profiles. The solver's box is ``[0, 1]``: the parameter is ``h = s /``
    :data:`SCALE_MAX`, so a declared intensity may be off by any factor up to 4 (the 10-20 % of a
    survey, with a large margin); an estimate at the bound says the emitter's shape or another
    unknown (an exposure) is wrong, not that the scale is 4. The pass's coefficients are physical
    (per unit ``s``); :meth:`Illumination.to_box` multiplies those of ``s`` by ``SCALE_MAX``.
    The start is the declared intensity (``s = 1``).

The gauge
    Reflected light is ``s · ρ`` to first order: a common scale of every emitter trades off with
    the reflectances, and only interreflections (``s ρ²``, ``s ρ³``) or directly seen emitters tell
    them apart, weakly. So a scene whose every emitter has an unknown scale and no segment is
    ``known`` (a calibration panel) is refused (:func:`check_gauge`): one emitter of known
    intensity, or one known segment, fixes the gauge.

    Per-view exposure gains (``exposure: per_view``) share a second trade-off with the scales: a
    view's pixels are ``g_v Σ_e s_e L_e(ρ)``, unchanged if every ``s_e`` is multiplied by ``k``
    and every ``g_v`` divided by it. The reference view's gains are 1 by definition, which
    removes ``k``: the scales are those of the light as the reference view's camera records it,
    the other views' gains relative to it; the ρ-versus-light trade-off above is unchanged by
    the gains and still needs a known emitter or segment.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from framework.errors import ConfigError
from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.emitter_groups import unknown_emitters
from methods.symbolic.system.pixel_matrices import scale_columns
from methods.symbolic.trace.monomial_codes import code_digits

#: ``s = SCALE_MAX · h``, ``h`` in the solver's box [0, 1] (module docstring)
SCALE_MAX = 4.0
#: ``segment_name`` of a scale parameter: this prefix, then the emitter's scene.yaml index (``/sun``,
#: ``/sky`` for the parts of a sunsky)
ILLUMINATION_PREFIX = "illumination:"


def check_gauge(scene) -> None:
    """Raise :class:`ConfigError` (one line, the remedies) when every emitter that gives light has
    an unknown scale and no segment is known: ρ and a common scale of the light trade off (module
    docstring). An emitter of known scale that gives no light (a sunsky's ``sun_scale: 0``, an
    irradiance of 0) fixes nothing, so it does not count."""
    emitters = [e for e in scene.emitters if _gives_light(e)]
    if not emitters or not all(e.scale_unknown for e in emitters):
        return
    if any(seg.known for seg in scene.segments):
        return
    where = f"{scene.root}/scene.yaml" if getattr(scene, "root", None) is not None else "scene.yaml"
    dark = sorted({_label(e.source, e.part) for e in scene.emitters if not _gives_light(e)}, key=str)
    but = f" (emitter {', '.join(dark)} gives no light, so its known scale fixes nothing)" if dark else ""
    raise ConfigError(f"{where}: every emitter's scale is unknown{but} and no segment is known, so the reflectances "
                      "and a common scale of the light cannot be told apart; give one emitter's scale as a number, "
                      "or mark a calibration panel with known: {kernel: value} on its segment")


def _gives_light(emitter) -> bool:
    """Whether ``emitter`` as declared gives any light (an unknown scale multiplies this)."""
    values = {"directional": emitter.irradiance, "constant": emitter.radiance,
              "envmap": emitter.image}.get(emitter.type)
    if values is None:
        return True                       # an area light: its meshes carry it
    return bool(np.any(np.asarray(values, float) > 0)) and (emitter.type != "envmap" or emitter.scale != 0)


def nominal(rho: np.ndarray, scene) -> np.ndarray:
    """``ρ`` (P, C) with a row of 1 per unknown scale appended: the declared light, in the
    physical units of the pass's coefficients."""
    G = len(unknown_emitters(scene))
    return np.vstack([rho, np.ones((G, rho.shape[1]))]) if G else rho


def pass_basis(n_params: int, max_bounces: int, scene, codes: np.ndarray) -> MonomialBasis:
    """The basis of a polynomial pass over ``n_params`` ρ: with ``G`` unknown scales, over
    ``n_params + G`` parameters of degree ``max_bounces + 1``."""
    G = len(unknown_emitters(scene))
    return MonomialBasis(n_params + G, max_bounces + (1 if G else 0), codes)


@dataclass(frozen=True)
class Illumination:
    """The unknown emitter scales of a run (module docstring).

    Attributes
    ----------
    emitters : tuple
        ``(index in scene.emitters, scene.yaml index, part)`` of each unknown scale, in group order.
    first : int
        Index of the first scale parameter (``D``).
    """

    emitters: tuple
    first: int

    @classmethod
    def of(cls, scene, *, first: int) -> "Illumination | None":
        """The scene's unknown scales (None when every emitter is known)."""
        found = tuple((j, scene.emitters[j].source, scene.emitters[j].part) for j in unknown_emitters(scene))
        return cls(found, int(first)) if found else None

    @property
    def n_parameters(self) -> int:
        return len(self.emitters)

    def parameters(self) -> list:
        """One :class:`~framework.scene.model.Parameter` per scale (kernel ``scale``, ``segment``
        below every other parameter's, ``segment_name`` ``illumination:<emitter>``)."""
        from framework.scene.model import Parameter
        return [Parameter(self.first + g, -1_000_000 - g, ILLUMINATION_PREFIX + _label(source, part), "scale")
                for g, (_, source, part) in enumerate(self.emitters)]

    def start(self, n_channels: int) -> np.ndarray:
        """``(G, C)`` start of ``h``: the declared intensity, ``s = 1``."""
        return np.full((self.n_parameters, n_channels), 1.0 / SCALE_MAX)

    def to_box(self, coeffs, *, max_degree: int):
        """A view's coefficients (over ``first + G`` parameters of degree ``max_degree``, per unit
        ``s``) as coefficients of ``h``: the columns of monomials holding a scale times
        :data:`SCALE_MAX`. Tiled coefficients are scaled block by block and held in memory."""
        from methods.symbolic.system.coefficients import TiledCoefficients, ViewCoefficients
        if isinstance(coeffs, TiledCoefficients):
            blocks = [self.to_box(b, max_degree=max_degree) for _, b in coeffs.blocks()]
            return TiledCoefficients(coeffs.starts, blocks, coeffs.n_rows)
        n = self.first + self.n_parameters
        digits = code_digits(np.asarray(coeffs.codes, np.int64), n, max_degree)
        factor = np.where((digits > self.first).any(axis=1), SCALE_MAX, 1.0)
        scale = lambda mats: None if mats is None else [scale_columns(m, factor) for m in mats]  # noqa: E731
        return ViewCoefficients(scale(coeffs.a), scale(coeffs.b), coeffs.split, coeffs.codes)

    def report(self, estimate: np.ndarray, std: np.ndarray) -> list[dict]:
        """results.json ``illumination`` from the solve's rows (the full ``(n_total, C)`` arrays):
        one entry per unknown scale, ``s`` and its std per channel."""
        out = []
        for g, (_, source, part) in enumerate(self.emitters):
            row = self.first + g
            out.append({"emitter": source, "part": part,
                        "estimate": _channels(SCALE_MAX * estimate[row]),
                        "std": _channels(SCALE_MAX * std[row])})
        return out


def _label(source, part) -> str:
    return f"{source}" if part is None else f"{source}/{part}"


def _channels(values: np.ndarray) -> list:
    """Per channel, NaN (not observable) as None."""
    return [None if not np.isfinite(v) else float(v) for v in np.asarray(values, float)]
