"""The views' alignment over the passes of one run (``method.align``), and its pose uncertainty
handed to the std.

Between two passes (:func:`methods.symbolic.loop.refinement.run_passes`) each view's observed
image is registered to the prediction at the pass's estimate
(:func:`~methods.symbolic.misfit.registration.register`) and the next pass renders the corrected
camera; :class:`Alignment` keeps each view's given camera, every registration and the total
correction, which stays within ``max_px`` of the given camera.

The camera the next pass renders is then known to the registration's precision only: each
view's covariance (:attr:`~methods.symbolic.misfit.registration.Registration.cov_px`, whether
the correction was applied or was within its noise) goes to the fit as
``Problem.pose_covariance``, and the std propagates it (the delta method: a pose error ``δ``
moves pixel ``p``'s residual by ``G_p δ``,
:func:`~methods.symbolic.misfit.registration.pose_sensitivity`; :func:`pose_terms` hands each
view's ``(G, Σ)`` to :func:`~methods.symbolic.uncertainty.sandwich_meat.score_meat`, which adds
``T Σ Tᵀ`` to the sandwich's meat). Measured on the bundled field and misfit scenes
(registrations within 0.006-0.03 px): it adds at most 6 % to the meat's diagonal, and the RMS of
error/std moved by less than 0.002; the pose's error is not what is left of their misfit.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from methods.symbolic.misfit.registration import pose_sensitivity, register
from methods.symbolic.misfit.turned_camera import correction


def pose_terms(problem, views):
    """Per view of ``views`` (``(coefficients, y, ...)`` in the order of ``problem.cameras``) None
    or ``(G, Σ)`` for :func:`~methods.symbolic.uncertainty.sandwich_meat.score_meat`, made as each view is
    reached (a megapixel view's ``G`` is 72 MB): the registered cameras' covariance
    (``problem.pose_covariance``, from ``method.align``) and the pixels' sensitivity to it. None
    when no camera was registered."""
    cov = problem.pose_covariance or {}
    if not any(v is not None for v in cov.values()):
        return None

    def term(cam, y):
        sigma = cov.get(cam.name)
        if sigma is None:
            return None
        image = np.asarray(y, float).reshape(cam.height, cam.width, -1)
        return pose_sensitivity(image, cam, roll=len(sigma) == 3), sigma
    return (term(cam, y) for cam, (_, y, *_) in zip(problem.cameras, views))



class Alignment:
    """The views' alignment over the passes of one run (``method.align``): each view's given
    camera, the registration of every pass and the cameras the next pass renders.

    Parameters
    ----------
    cameras : list of Camera
        The given cameras (the scene's poses).
    mode : str
        ``shift`` (pitch and yaw) or ``rotation`` (and roll).
    max_px : float
        Largest correction accepted, of one registration and in total from the given camera.
    min_px : float
        Smallest correction applied (:func:`~methods.symbolic.misfit.registration.register`).
    """

    def __init__(self, cameras, *, mode: str, max_px: float, min_px: float):
        if mode not in ("shift", "rotation"):
            raise ValueError(f"alignment mode '{mode}' unknown; use shift or rotation")
        self.given = {c.name: c for c in cameras}
        self.mode, self.max_px, self.min_px = mode, float(max_px), float(min_px)
        self.passes: dict[str, list] = {c.name: [] for c in cameras}

    def update(self, problem, fit, *, before_pass: int):
        """``problem`` with each view's camera registered to ``fit``'s prediction (its images at the
        estimate, weighted by its pixel weights); ``before_pass``: the pass that will render them."""
        predicted = fit.images()
        weights = fit.pixel_weights or {}
        clusters = _view_clusters(problem, fit)
        cameras, covariance = [], {}
        for cam in problem.cameras:
            reg = register(problem.observed[cam.name], predicted[cam.name], cam, weights=weights.get(cam.name),
                           max_px=self.max_px, min_px=self.min_px, roll=self.mode == "rotation",
                           clusters=clusters.get(cam.name))
            accepted, why = reg.accepted, reg.why
            total = correction(self.given[cam.name], reg.camera)["motion_px"]
            if accepted and total > self.max_px:
                accepted, why = False, f"the total correction {total:.2f} px is above the bound of {self.max_px:g} px"
            self.passes[cam.name].append({
                "pass": int(before_pass), "shift_px": list(reg.shift_px), "rotation_deg": reg.rotation_deg,
                "std_px": None if not np.isfinite(reg.std_px) else reg.std_px, "iterations": reg.iterations,
                "accepted": accepted, "why": why})
            cameras.append(reg.camera if accepted else cam)
            # the camera the next pass renders is known to the registration's precision, whether
            # corrected or kept (a correction within its noise)
            covariance[cam.name] = reg.cov_px
        return dataclasses.replace(problem, cameras=cameras, pose_covariance=covariance)

    def moved(self) -> bool:
        """Whether the last registrations corrected a camera: the pass rendered at it is then
        registered again before the passes stop."""
        return any(entries and entries[-1]["accepted"] for entries in self.passes.values())

    def report(self, cameras) -> list[dict]:
        """results.json ``alignment``: per view the total correction from the given camera to
        its camera in ``cameras`` and every registration (docs/results.md)."""
        out = []
        for cam in cameras:
            total = correction(self.given[cam.name], cam)
            entries = self.passes[cam.name]
            out.append({"view": cam.name, "shift_px": total["shift_px"], "rotation_deg": total["rotation_deg"],
                        "passes": entries, "accepted": bool(entries and entries[-1]["accepted"]),
                        "why": entries[-1]["why"] if entries else "no refinement pass ran"})
        return out


def _view_clusters(problem, fit) -> dict:
    """View name -> ``(H·W,)`` cluster ids of the fit's cluster std (its side, each view's segments),
    so that a registration's covariance counts correlated pixels as the std does; ``{}`` when the
    fit's std is the pixel sandwich."""
    side = (fit.clusters or {}).get("side") if fit.std_method == "cluster" else None
    if not side:
        return {}
    from framework.render.mitsuba_scene import segment_maps
    from methods.symbolic.misfit.clusters import cluster_ids
    maps = segment_maps(problem.scene, problem.cameras)
    return {name: cluster_ids(seg, int(side)) for name, seg in maps.items()}
