"""One view aligned to the model: its observed image registered to the prediction at the estimate.

COLMAP poses of a surveyed street are off by a fraction of a pixel; along a misregistered edge
hundreds of neighbouring residuals share one error, and the fit follows it. Between two passes
(:func:`methods.symbolic.loop.refinement.run_passes`, ``method.align``) each observed image is
registered to the prediction of the pass at its estimate by a small rotation of the camera about
its centre, and the next pass renders the corrected camera.

The model: a camera turned by the rotation ``R`` (``cam_from_world' = R · cam_from_world``, the
centre fixed) sees through pixel ``p`` what the given camera sees through
``q(p) = K Rᵀ K⁻¹ p`` (a homography; ``K`` the pinhole's intrinsics;
:mod:`methods.symbolic.misfit.turned_camera`). The rotation vector ``ω``
(about the camera's x, y, z axes: pitch, yaw, roll; roll held at 0 with ``roll=False``)
minimises ``Σ_p w_p Σ_c (m_c(q(p; ω)) - y_c(p))²`` over the usable pixels (weight ``w`` > 0, off
the image's outer ring, ``q`` inside the image), ``m`` the prediction (cubic-spline samples), ``y``
the observation, by Gauss-Newton: each step's Jacobian is ``∇y · ∂q/∂ω``, the observation's
gradient (central differences) standing for the warped prediction's (they are equal where the
two images match; the prediction's own gradient carries its Monte Carlo noise into the Jacobian,
which shrinks the correction and doubled the error, :func:`_normal_system`), iterated until a
step moves the image by less than :data:`STEP_TOL_PX` or a tenth of its standard error. To first
order yaw and pitch shift the image by ``f·ω`` pixels and roll turns it about the principal point.

A correction is applied only when

- well conditioned: the standard error of the motion at the principal point (the sandwich of
  the per-pixel scores, :func:`_covariance`) below :data:`MAX_STD_PX` (a view whose observation
  has no edge, a flat wall filling the frame, has none);
- significant: its Mahalanobis distance from no correction above the χ² quantile of level
  :data:`SIGNIFICANCE` (a correction within its noise would move a right camera by that noise);
- below ``max_px`` (the motion at the principal point, and the roll's at the image corner);
- at least ``min_px`` (the larger of those motions): the registration's standard error is too
  small where the prediction's Monte Carlo noise and the model's misfit share the image's
  structure (on the bundled field scene, poses right, corrections of 0.03-0.09 px passed the
  significance test at 3-5 standard errors and were undone by the next pass's registration),
  and the estimate follows each camera move.

Otherwise the camera is kept and :attr:`Registration.why` says why.

Limitations: a rotation about the camera centre only (a translation error of the pose shows as
parallax, which no rotation matches); the registration's precision is that of the pass's Monte
Carlo prediction (measured on a 64x64 view of the tiny scene, one registration erred by 0.10-0.28
px at 16 spp and 0.01-0.06 px at 256 spp), and its sandwich std took the measured spread
for about 1.5 times its size at 16 spp (hence the strict level).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from framework.scene.model import Camera
from methods.symbolic.misfit.turned_camera import centre_shift, pixel_grid, pixel_scale, rotated, warp

#: the Gauss-Newton iterations stop when a step moves the image by less than this (pixels) or
#: than a tenth of the motion's standard error (bilinear samples make the cost piecewise smooth:
#: the steps may cycle at that scale)
STEP_TOL_PX = 1e-3
#: cap on the Gauss-Newton iterations of one registration
MAX_ITERATIONS = 30
#: a correction whose motion has a larger standard error (pixels) is refused as ill-conditioned
MAX_STD_PX = 0.25
#: a correction is applied only when significant at this level (its Mahalanobis distance from 0,
#: χ² with one degree of freedom per angle): one within its noise would move a right camera by noise
SIGNIFICANCE = 0.001
#: least usable pixels of a registration (with fewer it is refused)
MIN_PIXELS = 16


@dataclass(frozen=True)
class Registration:
    """The registration of one view (:func:`register`).

    Attributes
    ----------
    rotation : numpy.ndarray
        ``(3,)`` rotation vector (radians, about the camera's x, y, z axes) of the correction
        found, whether accepted or not.
    shift_px : tuple of float
        ``(dx, dy)``: the motion of the content at the principal point, the observation minus the
        prediction (a feature the prediction shows at ``c`` the observation shows at ``c + d``).
    roll_px : float
        The roll's motion at the image corner (pixels).
    std_px : float
        Standard error of the motion at the principal point (the larger axis), NaN when singular.
    cov_px : numpy.ndarray or None
        ``(k, k)`` covariance of the correction in pixels of motion (pitch, yaw[, roll]; the
        sandwich of the last Gauss-Newton system), None when it did not converge, was singular
        or ill-conditioned.
    iterations : int
        Gauss-Newton iterations done.
    accepted : bool
        The correction is below ``max_px`` and well conditioned.
    why : str
        ``"accepted"``, or why the camera was kept.
    camera : Camera
        The corrected camera when accepted, else the given one.
    """

    rotation: np.ndarray
    shift_px: tuple[float, float]
    roll_px: float
    std_px: float
    cov_px: np.ndarray | None
    iterations: int
    accepted: bool
    why: str
    camera: Camera

    @property
    def rotation_deg(self) -> list[float]:
        """``[pitch, yaw, roll]``: the rotation vector in degrees (about x, y, z)."""
        return [float(v) for v in np.degrees(self.rotation)]


def register(observed: np.ndarray, predicted: np.ndarray, camera: Camera, *, weights: np.ndarray | None = None,
             max_px: float, min_px: float, roll: bool = True,
             clusters: np.ndarray | None = None) -> Registration:
    """Register ``observed`` to ``predicted`` by a small rotation of ``camera`` (module docstring).

    Parameters
    ----------
    observed, predicted : numpy.ndarray
        ``(H, W, C)`` (or ``(H, W)``) linear images of ``camera``'s size: the photograph and the
        model's image at the current estimate through ``camera``.
    camera : Camera
        The pinhole camera ``predicted`` was rendered through.
    weights : numpy.ndarray, optional
        ``(H, W)`` or ``(H·W,)`` pixel weights of the observation (0: not used; masks, robust
        weights); default all 1.
    max_px : float
        Largest correction accepted (pixels of motion at the principal point; the roll's at the
        image corner). Default 3.
    min_px : float
        Smallest correction applied (the larger of those two motions). Default 0.
    roll : bool
        Estimate the roll too (default); False: pitch and yaw only.
    clusters : numpy.ndarray, optional
        ``(H·W,)`` cluster id of each pixel (:func:`~methods.symbolic.misfit.clusters.cluster_ids`): the
        correction's covariance is then the cluster-robust sandwich (the scores summed within each
        cluster, CR1-corrected), as the std's; default each pixel its own cluster.

    Returns
    -------
    Registration
        With the corrected camera when accepted.

    Raises
    ------
    ValueError
        When the images do not have the camera's size, the weights the camera's pixel count, or
        ``max_px`` is not positive.
    """
    y, m = _as_hwc(observed), _as_hwc(predicted)
    H, W = camera.height, camera.width
    if y.shape != m.shape or y.shape[:2] != (H, W):
        raise ValueError(f"observed {y.shape[:2]} and predicted {m.shape[:2]} images must both have the camera's "
                         f"size {(H, W)}")
    w = np.ones(H * W) if weights is None else np.asarray(weights, float).reshape(-1)
    if w.shape != (H * W,):
        raise ValueError(f"weights of {w.size} pixels for a {H}x{W} view")
    if not max_px > 0:
        raise ValueError(f"max_px must be positive, got {max_px}")
    if not 0 <= min_px < max_px:
        raise ValueError(f"min_px must be in [0, max_px={max_px}), got {min_px}")
    if clusters is not None and np.shape(clusters) != (H * W,):
        raise ValueError(f"clusters of {np.size(clusters)} pixels for a {H}x{W} view")
    n_par = 3 if roll else 2
    scale = pixel_scale(camera)[:n_par]                          # radians -> pixels of motion
    # (H·W, C, 2) d/dx, d/dy of the observation (central differences): the Jacobian's image gradient
    grad = np.stack(np.gradient(y, axis=(1, 0)), axis=-1).reshape(H * W, y.shape[2], 2)
    px, yv, m = pixel_grid(camera), y.reshape(H * W, -1), _spline(m)
    omega, system = np.zeros(3), None
    why, iterations = "accepted", 0
    for iterations in range(1, MAX_ITERATIONS + 1):
        system = _normal_system(m, yv, grad, w, camera, omega, px, n_par, clusters)
        if system is None:
            why = f"fewer than {MIN_PIXELS} usable pixels inside the image"
            break
        A, b, _ = system
        step = _solve(A, -b)
        if step is None:
            why = "ill-conditioned: the observation has no gradient along some direction of the rotation"
            break
        omega[:n_par] += step / scale
        if np.max(np.abs(step)) < STEP_TOL_PX or np.max(np.abs(step)) < 0.1 * _motion_std(*system):
            break
        if np.linalg.norm(omega[:2] * scale[:2]) > 4 * max_px:
            why = f"diverged beyond {4 * max_px:g} px"
            break
    else:
        why = f"no convergence in {MAX_ITERATIONS} Gauss-Newton iterations"
    shift = centre_shift(camera, omega)
    roll_px = float(abs(omega[2]) * pixel_scale(camera)[2])
    std, cov = np.nan, None
    if why == "accepted":
        cov = _covariance(*system)
        why, std = _verdict(cov, omega[:n_par] * scale, shift, roll_px, max_px, min_px)
        cov = cov if std <= MAX_STD_PX else None     # ill-conditioned: none
    accepted = why == "accepted"
    return Registration(omega, (float(shift[0]), float(shift[1])), roll_px, std, cov, iterations, accepted, why,
                        rotated(camera, omega) if accepted else camera)


def pose_sensitivity(observed: np.ndarray, camera: Camera, *, roll: bool = True) -> np.ndarray:
    """``(H·W, C, k)``: how far each pixel's residual moves per pixel of motion of ``camera``'s
    pitch, yaw (and roll), ``∇y · ∂q/∂ω`` at ω = 0 with the observation's gradient (as in
    :func:`register`), row-major as the pixels. With a registration's covariance it gives the
    pose's share of the estimate's std (:func:`~methods.symbolic.uncertainty.sandwich_meat.score_meat`)."""
    y = _as_hwc(observed)
    H, W = camera.height, camera.width
    grad = np.stack(np.gradient(y, axis=(1, 0)), axis=-1).reshape(H * W, y.shape[2], 2)
    _, dq = warp(camera, np.zeros(3), pixel_grid(camera), 3 if roll else 2)
    return np.einsum("kcd,kdp->kcp", grad, dq)


def _verdict(cov: np.ndarray | None, motion: np.ndarray, shift: np.ndarray, roll_px: float, max_px: float,
             min_px: float) -> tuple[str, float]:
    """``(why, std_px)`` of a converged registration whose correction has covariance ``cov``
    (:func:`_covariance`, None when singular): ``accepted``, or why not (ill-conditioned, within
    its noise, below the smallest correction, above the bound); ``motion``: the correction in
    pixels of motion per parameter."""
    from scipy.stats import chi2
    std = float(np.sqrt(np.max(np.diag(cov)[:2]))) if cov is not None else np.nan
    if not np.isfinite(std) or std > MAX_STD_PX:
        return f"ill-conditioned: standard error {std:.2g} px above {MAX_STD_PX:g} px", std
    floor = (1e-6) ** 2 * np.eye(len(motion))        # noiseless residuals: any correction is significant
    distance = float(motion @ np.linalg.solve(cov + floor, motion))
    if distance < chi2.ppf(1.0 - SIGNIFICANCE, len(motion)):
        return (f"within its noise: correction {np.hypot(*shift):.3f} px, standard error {std:.3f} px "
                f"(not significant at {SIGNIFICANCE:g})"), std
    if max(np.hypot(*shift), roll_px) < min_px:
        return (f"below the smallest correction applied: {np.hypot(*shift):.3f} px (roll {roll_px:.3f} px at the "
                f"corner) under {min_px:g} px"), std
    if np.hypot(*shift) > max_px or roll_px > max_px:
        return (f"correction {np.hypot(*shift):.2f} px (roll {roll_px:.2f} px at the corner) above the bound of "
                f"{max_px:g} px"), std
    return "accepted", std


def _normal_system(m, yv, grad, w, camera: Camera, omega, px, n_par, clusters=None):
    """``(A, b, scores)`` of the Gauss-Newton step at ``omega`` in pixels of motion: ``A = JᵀWJ``,
    ``b = JᵀWr`` and the per-pixel scores ``(k, n_par)`` (summed over channels; with ``clusters``
    the clusters' :func:`_cluster_scores`); None with fewer than :data:`MIN_PIXELS` usable pixels
    (weight > 0, not on the image's outer ring, and ``q`` inside the image).

    ``r = m(q) - y`` and ``J = ∇y · ∂q/∂ω``: the observation's gradient stands for the warped
    prediction's (equal where they match), so that the Monte Carlo noise of the prediction enters
    the residual only, not the Jacobian (where it would shrink the correction towards 0 and add
    its noise twice): measured on the tiny scene at 16 spp, 32x32, the prediction's gradient
    erred by 0.27 px rms on a 1 px turn, the observation's by 0.13 px.
    """
    H, W = camera.height, camera.width
    q, dq = warp(camera, omega, px, n_par)          # (n, 2) x, y; (n, 2, n_par) per pixel of motion
    # not the outer ring (one-sided gradients; and pixels flipping in and out of the image at
    # ω = 0, where the centres of the outer ring lie on its border, made the steps cycle)
    ring = (px[:, 0] > 1) & (px[:, 0] < W - 1) & (px[:, 1] > 1) & (px[:, 1] < H - 1)
    use = (q[:, 0] >= 0.5) & (q[:, 0] <= W - 0.5) & (q[:, 1] >= 0.5) & (q[:, 1] <= H - 0.5) & (w > 0) & ring
    if use.sum() < MIN_PIXELS:
        return None
    J = grad[use] @ dq[use]                                           # (k, C, n_par)
    r = _sample(m, q[use]) - yv[use]                                  # (k, C)
    wJ = w[use][:, None, None] * J
    scores = (wJ * r[:, :, None]).sum(axis=1)
    b = scores.sum(axis=0)
    if clusters is not None:
        scores = _cluster_scores(scores, np.asarray(clusters)[use])
    # the pixels' and channels' sum as one matrix product (numpy's einsum loops in C without BLAS)
    return wJ.reshape(-1, n_par).T @ J.reshape(-1, n_par), b, scores


def _cluster_scores(scores: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """``(G, n_par)``: the pixels' scores summed within each cluster, centred and scaled by the
    square root of the CR1 factor, so that ``Σ_g S_g S_gᵀ`` is the cluster-robust meat of
    :mod:`methods.symbolic.misfit.clusters` (correlated neighbours count once)."""
    from methods.symbolic.misfit.clusters import cr1_factor
    _, ids = np.unique(ids, return_inverse=True)
    S = np.stack([np.bincount(ids, weights=scores[:, j]) for j in range(scores.shape[1])], axis=1)
    S -= S.mean(axis=0)
    return S * np.sqrt(cr1_factor(len(S), len(scores), scores.shape[1]))


def _covariance(A: np.ndarray, b: np.ndarray, scores: np.ndarray) -> np.ndarray | None:
    """Covariance (pixels of motion²) of the correction: the sandwich ``A⁻¹ (Σ_p s_p s_pᵀ) A⁻¹``
    of the per-pixel scores (pixels independent, each with its own variance: the edges of a
    Monte Carlo image are noisier than its flat parts); None when ``A`` is singular."""
    inv = _inverse(A)
    return None if inv is None else inv @ (scores.T @ scores) @ inv


def _motion_std(A: np.ndarray, b: np.ndarray, scores: np.ndarray) -> float:
    """Standard error (pixels) of the motion at the principal point, the larger axis; NaN when
    ``A`` is singular."""
    cov = _covariance(A, b, scores)
    return float("nan") if cov is None else float(np.sqrt(np.max(np.diag(cov)[:2])))


# ----------------------------------------------------------------------------------------------
# Images and algebra
# ----------------------------------------------------------------------------------------------

def _as_hwc(image: np.ndarray) -> np.ndarray:
    a = np.asarray(image, float)
    return a[..., None] if a.ndim == 2 else a


def _spline(image: np.ndarray) -> np.ndarray:
    """Cubic B-spline coefficients of each channel of ``image`` (H, W, C), for :func:`_sample`."""
    from scipy.ndimage import spline_filter
    return np.stack([spline_filter(image[..., c], order=3, mode="nearest") for c in range(image.shape[2])], axis=-1)


def _sample(coefficients: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Cubic-spline samples ``(k, C)`` of the image whose :func:`_spline` coefficients are given, at
    pixel coordinates ``q`` (x, y; centres at .5). Cubic, not bilinear: bilinear samples have a
    kink at every pixel centre, all crossed at once near the solution, and the Gauss-Newton steps
    cycled there (measured: the roll of a 64x64 view cycled by ±0.04 px)."""
    from scipy.ndimage import map_coordinates
    at = [q[:, 1] - 0.5, q[:, 0] - 0.5]
    return np.stack([map_coordinates(coefficients[..., c], at, order=3, mode="nearest", prefilter=False)
                     for c in range(coefficients.shape[2])], axis=1)


def _solve(A: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """``A⁻¹ b``, or None when ``A`` is singular (relative condition below 1e-10)."""
    inv = _inverse(A)
    return None if inv is None else inv @ b


def _inverse(A: np.ndarray) -> np.ndarray | None:
    values = np.linalg.eigvalsh(A)
    if not np.isfinite(values).all() or values[-1] <= 0 or values[0] <= 1e-10 * values[-1]:
        return None
    return np.linalg.inv(A)
