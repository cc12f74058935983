"""After the fit: the held-out views' predictions, image-space variances, metrics and images
(results.json ``holdout``; :mod:`framework.holdout` says what is predicted and how)."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from framework.holdout import (FD_STEP, PREDICTION_SEED, HeldOut, estimated_light, held_out_gain, lens_falloff,
                               predict, render_at)
from framework.holdout_metrics import view_metrics
from framework.images import write_exr
from framework.render.mitsuba_scene import segment_maps as view_segment_maps
from framework.results import image_paths, used_pixels


def fit_noise(problem, result) -> np.ndarray | None:
    """``(C,)``: the variance of the photographs' noise as the fit saw it, in unit-gain radiance
    (each fitted view's residual divided by its exposure gain and lens falloff, as a held-out
    view's variance is multiplied by its own: :class:`_Comparison`): the mean squared residual of
    the fitted views' reconstructions over the pixels the fit used, less the reconstructions' own
    Monte Carlo variance where the method reports it (``MethodResult.reconstruction_variance``: a
    reconstruction from a pass at ``render.spp`` carries that render's noise, which a held-out
    prediction at ``observe.spp`` does not); floored at 0. None when the method returned no
    reconstruction."""
    sq, mc, n = 0.0, 0.0, 0
    own = result.reconstruction_variance or {}
    gains = {e["view"]: np.asarray(e["estimate"], float) for e in result.extras.get("exposure") or []
             if e.get("estimate") and None not in e["estimate"]}
    cameras = {c.name: c for c in problem.cameras}
    for name, rec in result.reconstructions.items():
        used = used_pixels(problem, result, name)
        scale = np.broadcast_to(gains.get(name, 1.0) * lens_falloff(problem.scene, cameras[name], result.extras),
                                rec.shape)
        pick = (lambda a: a.reshape(-1, a.shape[-1])) if used is None else (lambda a: a[used])
        d = pick((rec.astype(float) - problem.observed[name]) / scale)
        sq, n = sq + (d * d).sum(axis=0), n + len(d)
        if name in own:
            mc = mc + pick(own[name].astype(float) / scale ** 2).sum(axis=0)
    return np.maximum(sq - mc, 0.0) / n if n else None


def observation_noise(problem, result, held: HeldOut, mc_var: dict) -> dict:
    """Variance ``(C,)`` of each held-out photograph's noise: rendered observations have the
    prediction's Monte Carlo variance (the same renderer at the same spp) plus ``observe.noise``'s
    Gaussian noise; photographs the noise the fit's residuals hold (:func:`fit_noise`; None when the
    method returned no reconstruction)."""
    if problem.scene.images is None:
        rel = problem.settings.observe.noise
        return {c.name: mc_var[c.name] + (rel * held.observed[c.name].mean()) ** 2 for c in held.cameras}
    noise = fit_noise(problem, result)
    return {c.name: noise for c in held.cameras}


#: Largest std a weight in [0, 1] can have to first order: that of a uniform distribution over
#: the box; an ill-determined weight's linearised std (often >> 1) is capped there.
STD_CAP = 1.0 / np.sqrt(12.0)


def covariance(result, params) -> np.ndarray | None:
    """``(C, P, P)`` covariance of the weights ``params`` from the method's ``std`` (capped at
    :data:`STD_CAP`) and the channel-mean ``correlation`` (identity without one); NaN std
    (unobservable, undetermined) counts as 0. None for a method without a std."""
    if result.std is None:
        return None
    std = np.nan_to_num(np.asarray(result.std, float)[[p.index for p in params]])      # (P, C)
    std = np.minimum(std, STD_CAP)
    corr = np.eye(len(params))
    table = result.extras.get("correlation") or {}
    if table.get("matrix"):
        at = {label: i for i, label in enumerate(table["labels"])}
        rows = [at.get(f"{p.segment_name}/{p.kernel}") for p in params]
        for i, a in enumerate(rows):
            for j, b in enumerate(rows):
                if a is not None and b is not None and i != j and table["matrix"][a][b] is not None:
                    corr[i, j] = table["matrix"][a][b]
    return np.einsum("pc,pq,qc->cpq", std, corr, std)


def jacobian_variance(problem, cameras, rho, params, cov: np.ndarray) -> dict:
    """``J Σ Jᵀ`` per pixel and channel of each view: ``J`` by forward differences of ``path``
    renders at ``render.spp`` that share their random numbers (the difference holds the pixel's
    derivative, not two renders' noise); only parameters with a non-zero variance are rendered."""
    spp, seed = problem.settings.spp, 2 * int(problem.seed) + PREDICTION_SEED + 1000
    live = [i for i in range(len(params)) if np.any(np.diagonal(cov, axis1=1, axis2=2)[:, i] > 0)]
    base = render_at(problem, cameras, rho, params, spp=spp, seed=seed)
    out = {c.name: np.zeros_like(base[c.name], dtype=float) for c in cameras}
    if not live:
        return out
    grads = {}
    for i in live:
        step = -FD_STEP if np.max(rho[i]) + FD_STEP > 1 else FD_STEP
        moved = rho.copy()
        moved[i] += step
        img = render_at(problem, cameras, moved, params, spp=spp, seed=seed)
        grads[i] = {n: (img[n] - base[n]) / step for n in img}
    for c in cameras:
        J = np.stack([grads[i][c.name] for i in live], axis=-1)                  # (H, W, C, L)
        sub = cov[:, live][:, :, live]                                           # (C, L, L)
        out[c.name] = np.einsum("hwcl,clm,hwcm->hwc", J, sub, J)
    return out


def _variances(problem, result, held: HeldOut, lit, rho, params, mc_var: dict, noise: dict) -> dict:
    """Predicted residual variance of each held-out pixel, per view: the observation noise, the
    prediction's Monte Carlo variance and ``J Σ Jᵀ`` (each view under its light, the fit's
    ``lit``; None where the observation noise is unknown)."""
    cov = covariance(result, params)
    model = {}
    if cov is not None:
        model, = _by_light(problem, held, lit, lambda p, cams: (jacobian_variance(p, cams, rho, params, cov),))
    return {c.name: None if noise[c.name] is None else noise[c.name] + mc_var[c.name] + model.get(c.name, 0.0)
            for c in held.cameras}


def light_groups(problem, held: HeldOut, scene) -> list:
    """``[(problem, cameras)]``: the held-out views grouped by the scene they are lit by, each with
    ``problem`` on that scene: ``scene`` (the fit's light) for the views of the fit's light, their
    own light's (:attr:`HeldOut.scenes`) for the others."""
    groups: dict = {}
    for c in held.cameras:
        lit = held.scene_of(c.name, scene)
        groups.setdefault(lit.light, (dataclasses.replace(problem, scene=lit), []))[1].append(c)
    return list(groups.values())


def _by_light(problem, held: HeldOut, scene, fn) -> tuple:
    """``fn(problem, cameras)`` (a tuple of dicts by view) on each light group (:func:`light_groups`),
    the dicts merged."""
    merged = None
    for p, cams in light_groups(problem, held, scene):
        out = fn(p, cams)
        merged = out if merged is None else tuple({**a, **b} for a, b in zip(merged, out))
    return merged


def holdout_entries(problem, result, held: HeldOut, run_dir: Path | None = None) -> list[dict]:
    """results.json ``holdout``: one entry per held-out view (docs/results.md), with its
    ``floor`` (the same metrics of a prediction at the scene's ``reference`` weights, when every
    weight has one, its variance the noise terms alone); the photograph and the prediction as
    EXRs under ``images/holdout/`` when ``run_dir`` is given. A view photographed under another
    light than the fitted views' is predicted under that light (:attr:`HeldOut.scenes`)."""
    if not held.cameras:
        return []
    floor = _floor(problem, held)
    params = list(result.parameters or problem.parameters)
    rho = np.nan_to_num(np.asarray(result.estimate, float)[[p.index for p in params]])
    lit = estimated_light(problem.scene, result.extras)
    preds, mc_var = _by_light(problem, held, lit, lambda p, cams: predict(p, cams, rho, params))
    noise = observation_noise(problem, result, held, mc_var)
    variances = _variances(problem, result, held, lit, rho, params, mc_var, noise)
    seg = view_segment_maps(problem.scene, held.cameras)
    paths = image_paths(c.name for c in held.cameras)
    entries = []
    for c in held.cameras:
        compare = _Comparison.of(problem, held, c, result.extras, preds[c.name], seg[c.name])
        entry = {**compare.metrics(preds[c.name], variances[c.name]), "gain": [float(g) for g in compare.gain],
                 "light": held.scene_of(c.name, problem.scene).light}
        if floor is not None:       # the truth's prediction, its gain fitted the same way
            entry["floor"] = _Comparison.of(problem, held, c, result.extras, floor[0][c.name], seg[c.name]).metrics(
                floor[0][c.name], None if noise[c.name] is None else noise[c.name] + floor[1][c.name])
        if run_dir is not None:
            entry["images"] = _write(run_dir, paths[c.name], held.observed[c.name],
                                     (preds[c.name] * compare.scale).astype(np.float32), problem.scene.channels)
        entries.append(entry)
    return entries


@dataclasses.dataclass
class _Comparison:
    """One held-out view's photograph against unit-gain predictions."""

    problem: object
    held: HeldOut
    camera: object
    gain: np.ndarray                       # (C,)
    scale: np.ndarray                      # gain times lens falloff, broadcast to (H, W, C)
    segment_map: np.ndarray

    @classmethod
    def of(cls, problem, held: HeldOut, camera, extras: dict, unit_prediction: np.ndarray, segment_map) -> "_Comparison":
        """The comparison of ``camera``'s photograph with ``unit_prediction`` through its lens's
        falloff and its gain (:func:`~framework.holdout.held_out_gain`)."""
        falloff = lens_falloff(problem.scene, camera, extras)
        gain = held_out_gain(extras, held.observed[camera.name], unit_prediction * falloff, held.used(camera.name))
        return cls(problem, held, camera, gain, gain * falloff, segment_map)

    def metrics(self, unit_prediction: np.ndarray, unit_variance) -> dict:
        """``view`` and :func:`view_metrics` of the prediction scaled by :attr:`scale` (its
        variance by its square; None: no ``z_rms``)."""
        name = self.camera.name
        var = None if unit_variance is None else unit_variance * self.scale ** 2
        return {"view": name, **view_metrics(self.held.observed[name], unit_prediction * self.scale,
                                             self.held.used(name), self.segment_map,
                                             [s.name for s in self.problem.scene.segments], variance=var)}


def _floor(problem, held: HeldOut):
    """Predictions at the scene's ``reference`` weights, each view under its light as declared
    (None when some weight has none)."""
    params = problem.parameters
    ref = problem.scene.reference(params)
    if ref is None or np.isnan(ref).any():
        return None
    return _by_light(problem, held, problem.scene, lambda p, cams: predict(p, cams, ref, params))


def _write(run_dir: Path, base: str, observed, predicted, channels) -> dict:
    """The held-out photograph and its prediction as EXRs under ``images/holdout/``."""
    rel = base.replace("images/", "images/holdout/", 1)
    target = Path(run_dir) / rel
    target.parent.mkdir(parents=True, exist_ok=True)
    write_exr(Path(f"{target}.observed.exr"), observed, channels)
    write_exr(Path(f"{target}.prediction.exr"), predicted, channels)
    return {"observed": f"{rel}.observed.exr", "prediction": f"{rel}.prediction.exr"}
