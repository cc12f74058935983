"""The finite-spp bias of the solve, estimated from the pass itself and removed
(``method.bias=richardson``).

The cross Gram makes the cost unbiased by the pass's Monte Carlo noise, but not the estimate:
ρ̂ is a non-linear function of the noisy coefficients (the inverse of G, the robust weights and
their scale, the exposure gains, the PSD projection), so ``E[ρ̂_n] = ρ + β/n + O(n⁻²)`` at ``n``
samples per pixel. Measured on the bundled field scene (64 spp): the window's mirror weight
erred −0.026 (R), −0.012 at 128 spp, and its error grew four-fold from 64 to 16 spp.

The pass keeps each pixel's samples as four independent quarters (:class:`ViewCoefficients`
``a1``, ``b1``), so the same render also gives two passes of ``n/2`` samples: the quarters of
the first half, and those of the second (:meth:`PassResult.halved`). Each is fitted exactly as
the pass was (same guesses, same start), and their mean ρ̂_{n/2} has bias 2β/n. Then
(Richardson extrapolation)::

    β̂ = ρ̂_{n/2} − ρ̂_n   estimates the bias β/n,     ρ̃ = ρ̂_n − β̂ = 2ρ̂_n − ρ̂_{n/2}

has none at order 1/n. To first order in the noise the two half fits' mean moves with the same
combination of the four quarters as ρ̂_n itself (each is a linear function of the mean of its
quarters with the same derivative), so β̂ carries no first-order noise and ``std``, the
first-order standard error of ρ̂_n, is left as it is. Its second-order noise (products of two
quarters' noises, the terms that make the bias) is larger: with the variance v of one product
term, ρ̂_n holds v/4 of it and ρ̃ 4·v/4 + v/2, about 2.4 times the standard deviation where those
terms dominate. Which wins depends on where the bias comes from. The plain L2 cost's only
non-linearity is the inverse of G, whose bias falls as 1/N with the N pixels while that noise
falls as 1/√N: on the tests' tiny rendered scene (4 views of 32x32, 64 spp, 10 seeds) the
corrected estimates spread 2.5-2.9 times more than the plain ones and the bias removed was
within that noise, so ``auto`` does not correct rendered linear radiance. The field path weighs
each pixel by a function of its own noisy residual (robust weights, their scale, the gains): a
bias per pixel that does not average out over the pixels, so it outgrows the noise as √N. On the
bundled field scene (9 views of 200x200, 64 spp) the worst specular error went from 0.026 to
0.005 (BENCHMARKS.md section 7). The price: the pass stores twice the coefficients (disk with a
cache), and the last pass is solved three times.

Limitations: a weight the fit puts on its bound 0 is not extrapolated, nor its segment's other
weights when a half fit moves one of them onto or off the bound (measured: on the field scene
with ``method.footprint=pixel`` the awning's mirror weight sat at 0 while the half fits found
0.12, and the extrapolation gave -0.12 to it and +0.036 to the awning's diffuse weight), nor
a segment whose extrapolated weights would leave the feasible set (a weight below 0 or above 1,
their sum above 1: on ``urban_canyon_survey`` a balcony's mirror weight, solved just above 0,
was extrapolated to −0.061); results.json ``spp_bias.correction`` says which held for each weight;
``spp`` a multiple of 4 and ``method.gram=cross``; only the weights ρ are
corrected (exposure gains, vignetting and emitter scales are reported as fitted); a bias that
does not fall as 1/n (a model the photographs do not follow) is not seen, and where the
estimate's error is not of that form the extrapolation can add to it: on ``urban_canyon_survey``
(unknown sun and sky scales, vignetting, a known panel; BENCHMARKS.md section 10, row b) the bias
removed had the sign of the error, not the opposite, and the worst errors doubled (diffuse 0.0026
to 0.0057, specular 0.0074 to 0.0148 where a weight on its bound was extrapolated too, 0.0076 with
the rule above; RMS z 1.42 to 2.47 with the cluster std; still within that section's targets). The plain estimate's error there moves with spp
towards the corrected one
(window ρ_s, R: −0.0003, +0.0020, +0.0029 at 32, 64, 128 spp; corrected at 64 spp +0.0064; wall
ρ_d +0.0024 and +0.0035 at 64 and 128, corrected +0.0047): the survey scene holds an error that
does not fall with spp, of the opposite sign to its finite-spp bias, which the plain estimate
masked; the correction uncovers it (with the light and the lens given at their true values it is
larger: window ρ_s +0.0085 plain, +0.0147 corrected). Its source is open (docs/design-notes.md).
``method.bias=none`` gives the estimate as solved.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from methods.symbolic.fit.fit import Fit


#: an estimate within this of 0 sits on its bound (the solver's box ρ >= 0) and is not extrapolated
AT_BOUND = 1e-9

#: what the correction did to each weight (results.json ``spp_bias.correction``): extrapolated;
#: kept as solved because a half fit did not observe it, because it sits on its bound 0, because
#: the fits disagree on which weights of its segment sit on it, or because the extrapolated
#: weights of its segment would leave the feasible set (a weight outside [0, 1], Σρ > 1)
ACTIONS = ("corrected", "not observed", "on its bound", "bounds differ", "infeasible")


def extrapolated(fit: Fit, refit: Callable[[int], Fit], *, segments: list[list[int]] | None = None) -> Fit:
    """``fit`` with its estimate ρ̂_n replaced by 2ρ̂_n − ρ̂_{n/2} (module docstring).

    Parameters
    ----------
    fit : Fit
        The fit of a pass that kept quarters (``polynomial_pass(..., quarters=True)``), from all
        its samples.
    refit : callable
        ``refit(j) -> Fit``: the fit ``fit`` came from, applied to that pass's half ``j`` (0, 1;
        :meth:`~methods.symbolic.system.coefficients.PassResult.halved`).
    segments : list of list of int, optional
        The parameter indices of each segment (whose weights share Σρ <= 1 and trade against
        each other): where a half fit puts a weight of the segment on its bound 0 and the whole
        fit does not, or the reverse, none of the segment's weights in that channel is
        extrapolated. None: every parameter its own segment.

    Returns
    -------
    Fit
        ``estimate`` extrapolated where both half fits observed the parameter, it is off its
        bound 0, its segment's weights are on the bound in all three fits or in none, and the
        segment's extrapolated weights stay feasible (each in [0, 1], their sum at most 1);
        ``spp_bias`` the (P, C) bias removed, NaN where it was not; ``spp_bias_actions`` (P, C)
        which of :data:`ACTIONS` applied. ``evaluated_at`` (and the reconstructions) stay at the
        estimate as solved: the polynomials are those of ρ̂_n's pass.
    """
    halves = [refit(j).estimate for j in (0, 1)]
    beta = 0.5 * (halves[0] + halves[1]) - fit.estimate        # NaN where a half did not observe it
    groups = segments if segments is not None else [[i] for i in range(len(beta))]
    actions = np.full(beta.shape, ACTIONS[0], dtype=object)
    actions[~np.isfinite(beta)] = "not observed"
    # at the bound ρ = 0 the estimate is not smooth in the noise, so its bias has no 1/n
    # expansion: a weight on it is kept as solved, and so is every weight of its segment when the
    # half fits and the whole one disagree on which weights are on it (the others trade with it)
    at = [np.abs(x) <= AT_BOUND for x in (fit.estimate, *halves)]
    actions[(actions == ACTIONS[0]) & at[0]] = "on its bound"
    for group in groups:
        differs = np.any((at[0][group] != at[1][group]) | (at[0][group] != at[2][group]), axis=0)
        _mark(actions, group, differs, "bounds differ")
    # an extrapolation out of the feasible set is the expansion failing near a bound the whole fit
    # did not reach: the segment keeps its weights as solved there, as on the bound
    trial = np.where(actions == ACTIONS[0], fit.estimate - beta, fit.estimate)
    for group in groups:
        _mark(actions, group, _infeasible(trial[group]), "infeasible")
    known = actions == ACTIONS[0]
    return fit.replace(estimate=np.where(known, fit.estimate - beta, fit.estimate),
                       spp_bias=np.where(known, beta, np.nan), spp_bias_actions=actions)


def _mark(actions: np.ndarray, group: list[int], channels: np.ndarray, why: str) -> None:
    """Mark the still corrected weights of ``group`` in the ``channels`` (a (C,) mask) with ``why``."""
    block = actions[np.ix_(group, np.flatnonzero(channels))]
    block[block == ACTIONS[0]] = why
    actions[np.ix_(group, np.flatnonzero(channels))] = block


def _infeasible(rho: np.ndarray) -> np.ndarray:
    """``(C,)`` whether a segment's weights ``rho`` (k, C) leave the solver's feasible set."""
    with np.errstate(invalid="ignore"):
        outside = np.any((rho < 0) | (rho > 1), axis=0)
        return outside | (np.nansum(rho, axis=0) > 1 + AT_BOUND)
