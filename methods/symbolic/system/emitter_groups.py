"""Which emitters the polynomial pass keeps apart: a group per emitter of unknown scale, and the
parts of a summed environment.

Light is additive in its emitters, so the pass keeps the light of each emitter of unknown scale
(scene.yaml ``scale: unknown``) apart: the integrator's path keys carry the emitter's group
(:func:`~methods.symbolic.trace.monomial_codes.emitter_columns`), group ``g + 1`` for the
``g``-th of :func:`unknown_emitters`, 0 for light of known intensity. Mitsuba renders the sum of
several environments; with one of them of unknown scale the pass splits them again
(:func:`split_environments`). The scales as parameters of the fit are
:mod:`methods.symbolic.survey.illumination`'s.
"""
from __future__ import annotations

from framework.render.mitsuba_scene import environments


def unknown_emitters(scene) -> list[int]:
    """Indices into ``scene.emitters`` of the emitters of unknown scale, in order: the ``g``-th of
    them is group ``g + 1`` of the polynomial pass."""
    return [j for j, e in enumerate(scene.emitters) if e.scale_unknown]


def split_environments(scene) -> list[int]:
    """Indices into ``scene.emitters`` of the environments the polynomial pass splits: Mitsuba
    renders their sum, and with more than one, one of them of unknown scale, each part's light is
    kept apart (:meth:`~methods.symbolic.trace.integrator.PolynomialPathMixin._store_site`); else none."""
    env = environments(scene)
    return env if len(env) > 1 and any(scene.emitters[j].scale_unknown for j in env) else []
