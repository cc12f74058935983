"""Pieces shared by the methods.

* :class:`StartOptions`, the options every method has (``init``, ``guess``);
* the initial guess (``guess`` number or per-kernel mapping, or ``init: lambertian_prior``);
* the feasible set of the weights (bounds [0, 1] and, per segment and channel, Σ_kernels ρ <= 1):
  nlopt constraint groups and a Euclidean projection;
* :class:`RenderLedger`: counts full passes over the views against ``budget.renders``, times
  Mitsuba, shows a tqdm bar;
* the image cost of the paper's eq. 6 with p = 2, squared, per channel.
"""
from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping

import numpy as np

from framework import optim
from framework.errors import ConfigError
from framework.options import ANY, choice, option
from framework.registry import Method, MethodResult
from framework.render.mitsuba_scene import max_depth_for


# ------------------------------------------------------------------------------------------------
# Options every method has
# ------------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class StartOptions:
    """``method.init`` and ``method.guess``: where a method starts."""

    init: str = option(
        "start point: `guess`, or the diffuse estimates of a `lambertian_prior` run with its shipped "
        "options but one pass and the joint cost, the cost of the fits it starts (its pass counts as a "
        "render against the budget; the other kernels keep `guess`)", choice("guess", "lambertian_prior"),
                default="guess")
    guess: float | dict = option(
        "initial weights: a number in [0, 1], or a mapping kernel → number with one entry per kernel "
        "of the scene, e.g. `{diffuse: 0.5, specular: 0.1}`; projected onto Σρ ≤ 1. For `symbolic` "
        "they also drive the kernel selection of the pass", ANY, default=0.5)


# ------------------------------------------------------------------------------------------------
# Initial guess and feasible set
# ------------------------------------------------------------------------------------------------
def initial_guess(options: StartOptions, problem, *, prior: Callable | None = None) -> tuple[np.ndarray, int]:
    """(P, C) start weights and the renders spent to get them.

    ``options.init``: ``guess`` uses ``options.guess`` (a number for every kernel, or a mapping
    kernel -> number); ``lambertian_prior`` calls ``prior(problem)`` (the Lambertian prior's
    :class:`~framework.registry.MethodResult`: the method passes it, so this module imports no
    method) and takes its diffuse estimates, the other kernels keeping ``options.guess``. The result
    is projected onto the feasible set.
    """
    rho = _guess_from_config(options.guess, problem)
    spent = 0
    if options.init == "lambertian_prior":
        rho, spent = _from_prior(rho, prior(problem), problem)
    return project_feasible(rho, problem.parameters), spent


def _guess_from_config(guess, problem) -> np.ndarray:
    kernels = {p.kernel for p in problem.parameters}
    if isinstance(guess, Mapping):
        missing = kernels - set(guess)
        if missing:
            raise ConfigError(f"method.guess={dict(guess)} lacks kernel(s) {', '.join(sorted(missing))}: "
                              f"give one number in [0, 1] per kernel of the scene ({', '.join(sorted(kernels))})")
        values = {k: guess[k] for k in kernels}
    else:
        values = {k: guess for k in kernels}
    for k, v in values.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v <= 1.0:
            raise ConfigError(f"method.guess={guess} is out of range: use a number in [0, 1] "
                              f"or a mapping kernel -> number in [0, 1] (kernel {k})")
    C = problem.n_channels
    return np.array([[float(values[p.kernel])] * C for p in problem.parameters])


def _from_prior(rho: np.ndarray, result, problem) -> tuple[np.ndarray, int]:
    """``rho`` with the finite estimates of the prior's ``result`` written in; its renders."""
    got = {(p.segment, p.kernel): result.estimate[i]
           for i, p in enumerate(result.parameters or problem.parameters)}
    rho = rho.copy()
    for p in problem.parameters:
        value = got.get((p.segment, p.kernel))
        if value is not None and np.all(np.isfinite(value)):
            rho[p.index] = value
    return rho, int(result.renders)


def segment_groups(parameters) -> list[list[int]]:
    """Parameter indices of each segment (the kernels whose weights share Σ ρ <= 1)."""
    groups: dict[int, list[int]] = {}
    for p in parameters:
        groups.setdefault(p.segment, []).append(p.index)
    return list(groups.values())


def flat_constraint_groups(parameters, n_channels: int) -> list[list[int]]:
    """Indices into ``ρ.ravel()`` (P, C) of each (segment, channel) sum constraint."""
    return [[i * n_channels + c for i in g] for g in segment_groups(parameters) for c in range(n_channels)]


def project_feasible(rho: np.ndarray, parameters) -> np.ndarray:
    """ρ (P, C) projected per channel onto [0, 1] ∩ {Σ_segment kernels ρ <= 1}
    (:func:`framework.optim.project_feasible` with the segments' index groups)."""
    return optim.project_feasible(rho, segment_groups(parameters))


# ------------------------------------------------------------------------------------------------
# Renders: cost, budget, timing
# ------------------------------------------------------------------------------------------------
def channel_costs(images: list[np.ndarray], observed: list[np.ndarray], weights: list | None = None) -> np.ndarray:
    """(C,) Σ over views and pixels of w·(render - observed)² per channel (paper eq. 6, p = 2,
    squared); ``weights``: per view an (H, W, 1) array (:func:`weights_list`) or None (all 1)."""
    weights = weights or [None] * len(images)
    return sum(np.sum(np.square(img.astype(np.float64) - obs) * (1.0 if w is None else w), axis=(0, 1))
               for img, obs, w in zip(images, observed, weights))


def observed_list(problem) -> list[np.ndarray]:
    """Observed images in the order of ``problem.cameras`` (the Mitsuba sensors' order)."""
    return [np.asarray(problem.observed[c.name], dtype=np.float64) for c in problem.cameras]


def weights_list(problem) -> list | None:
    """The scene's pixel weights (0: masked, saturated, outside the delivered image) as (H, W, 1)
    arrays in the order of ``problem.cameras``; None when every pixel counts."""
    if problem.weights is None:
        return None
    return [np.asarray(problem.weights[c.name], dtype=np.float64)[..., None] for c in problem.cameras]


def refuse_per_view_exposure(problem, method: str) -> None:
    """Raise :class:`ConfigError` when the scene's photographs have unknown per-view exposure,
    which a re-rendering baseline does not estimate."""
    photometry = getattr(problem.scene, "photometry", None)
    if photometry is not None and photometry.exposure == "per_view":
        raise ConfigError(f"method={method} does not estimate per-view exposure gains (scene.yaml "
                          "photometry exposure: per_view): use method=symbolic or lambertian_prior, "
                          "or set exposure: known if the photographs share one calibrated exposure")


class RenderLedger:
    """Counts full passes over the views against a budget; times them; drives a tqdm bar.

    Parameters
    ----------
    budget : int
        ``budget.renders``: the most passes the method may spend.
    desc : str
        Label of the progress bar.
    spent : int
        Passes already spent (for example by an initial-guess method).
    """

    def __init__(self, budget: int, *, desc: str, spent: int = 0):
        from tqdm import tqdm
        self.budget = int(budget)
        self.used = int(spent)
        self.render_s = 0.0
        self._bar = tqdm(total=self.budget, initial=self.used, desc=desc, unit="render", leave=False)

    def left(self) -> int:
        return self.budget - self.used

    def can_afford(self, n: int) -> bool:
        return self.used + n <= self.budget

    def spend(self, n: int, seconds: float) -> None:
        """Record ``n`` passes that took ``seconds`` in Mitsuba."""
        if not self.can_afford(n):
            raise RuntimeError(f"render budget exceeded: {self.used} + {n} > {self.budget}")
        self.used += n
        self.render_s += seconds
        self._bar.update(n)

    def close(self) -> None:
        self._bar.close()


def render_pass(ms, *, spp: int, seeds: list[int], ledger: RenderLedger) -> list[np.ndarray]:
    """One full pass: every sensor of ``ms`` rendered once (seed ``seeds[v]``); counts 1 render."""
    if not ledger.can_afford(1):
        raise RuntimeError(f"render budget exceeded: {ledger.used} + 1 > {ledger.budget}")
    t0 = time.perf_counter()
    images = [ms.render(v, spp=spp, seed=s) for v, s in enumerate(seeds)]
    ledger.spend(1, time.perf_counter() - t0)
    return images


def reconstruction_pass(ms, *, spp: int, seeds: list[int], ledger: RenderLedger) -> tuple[list, list | None]:
    """The reconstructions at the estimate, one full pass (counts 1 render) rendered as two
    independent parts of ``spp // 2`` and ``spp - spp // 2`` samples per view: their
    sample-weighted mean, and each pixel's Monte Carlo variance ``s (1 - s) (a - b)²`` (``s`` the
    first part's share; the same estimate as the symbolic pass's halves). A held-out view's noise
    model takes the reconstructions' own noise out of their residuals
    (:func:`framework.holdout_run.fit_noise`). ``spp`` 1: the render alone, variances None."""
    if spp < 2:
        return render_pass(ms, spp=spp, seeds=seeds, ledger=ledger), None
    if not ledger.can_afford(1):
        raise RuntimeError(f"render budget exceeded: {ledger.used} + 1 > {ledger.budget}")
    t0 = time.perf_counter()
    first = spp // 2
    s = first / spp
    images, variances = [], []
    for v, seed in enumerate(seeds):
        a = ms.render(v, spp=first, seed=seed)
        b = ms.render(v, spp=spp - first, seed=seed + SECOND_PART_SEED)
        images.append((s * a + (1 - s) * b).astype(np.float32))
        variances.append((s * (1 - s) * (a - b) ** 2).astype(np.float32))
    ledger.spend(1, time.perf_counter() - t0)
    return images, variances


#: what the second part of a reconstruction adds to its view's seed (:func:`reconstruction_pass`)
SECOND_PART_SEED = 104729


class Trace:
    """The iterates of a method, for error-against-time curves (results.json ``trace``).

    ``record(renders, estimate)`` at each iterate (the estimate the method would return if it
    stopped there); :meth:`entries` thins to at most ``at_most`` entries, evenly in order,
    always keeping the first and the last.
    """

    def __init__(self, started: float):
        self.started = started
        self._items: list[tuple[float, int, np.ndarray]] = []

    def record(self, renders: int, estimate: np.ndarray, *, at: float | None = None) -> None:
        now = time.perf_counter() if at is None else at
        self._items.append((now - self.started, int(renders), np.array(estimate, dtype=float)))

    def entries(self, at_most: int = 500) -> list[dict]:
        n = len(self._items)
        keep = range(n) if n <= at_most else np.unique(np.linspace(0, n - 1, at_most).round().astype(int))
        return [{"time_s": self._items[i][0], "renders": self._items[i][1],
                 "estimate": [[None if not np.isfinite(v) else float(v) for v in row]
                              for row in self._items[i][2]]} for i in keep]


def with_seed(problem, seed: int):
    """``problem`` with the run seed ``seed`` (its renders then use other Mitsuba seeds)."""
    return dataclasses.replace(problem, settings=dataclasses.replace(problem.settings, seed=int(seed)))


def render_once(problem, seed: int, desc: str, render: Callable) -> dict[str, np.ndarray]:
    """``render(problem, ledger)`` (one full pass: a list of images, one per view) with the run seed
    ``seed``, by view name: a render-in-the-loop method's :meth:`~framework.registry.Method.render_at`."""
    problem = with_seed(problem, seed)
    ledger = RenderLedger(1, desc=desc)
    try:
        images = render(problem, ledger)
    finally:
        ledger.close()
    return {c.name: img for c, img in zip(problem.cameras, images)}


def max_depth(problem) -> int:
    """Mitsuba ``max_depth`` for the run's ``render.max_bounces`` and ``render.tail_bounces``
    (N_max + T + 1: a baseline renders every reflection the symbolic pass traces)."""
    return max_depth_for(problem.settings.max_bounces + problem.settings.tail_bounces)


def loop_result(problem, ledger: RenderLedger, *, started: float, rho: np.ndarray, costs: list[float],
                times: list[float], reconstructions: tuple[list, list | None], extras: dict, trace: Trace):
    """The :class:`~framework.registry.MethodResult` of a render-in-the-loop method: Mitsuba time
    is ``render``, the rest of the wall time since ``started`` is ``solve``; ``reconstructions``
    as :func:`reconstruction_pass` returns them (``([], None)``: none)."""
    total = time.perf_counter() - started
    images, variances = reconstructions
    return MethodResult(
        estimate=rho, renders=ledger.used,
        timings_s={"render": ledger.render_s, "solve": total - ledger.render_s},
        cost_history=costs, cost_times_s=times, trace=trace.entries(),
        reconstructions={c.name: img for c, img in zip(problem.cameras, images)},
        reconstruction_variance=None if variances is None else
        {c.name: v for c, v in zip(problem.cameras, variances)},
        extras=extras)


class RenderingBaseline(Method):
    """A method that renders the scene again at its iterates (``iterative``, ``differentiable``):
    it does not estimate per-view exposure gains, so such photographs are refused up front."""

    def check_problem(self, problem) -> None:
        refuse_per_view_exposure(problem, self.name)

    def _start(self, problem, prior) -> tuple[float, np.ndarray, "RenderLedger"]:
        """``(t0, ρ0, ledger)``: the checks, the clock, the initial guess (``prior`` for
        ``method.init=lambertian_prior``) and the render ledger with the prior's renders spent."""
        self.check_problem(problem)
        t0 = time.perf_counter()
        rho0, spent = initial_guess(self.options, problem, prior=prior)
        return t0, rho0, RenderLedger(problem.settings.budget_renders, desc=self.name, spent=spent)
