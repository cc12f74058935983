"""Error against time, from the ``trace`` of results.json (``docs/results.md``).

Every method records its iterates: the estimate it would return if it stopped there, with the
wall time since it started and the renders spent. Against the references this gives, per run,
the worst and the mean absolute error over every parameter and channel that has a reference and
a finite estimate, as a function of time. Comparing methods at *equal error* instead of equal
budget: the time a baseline needs to reach the symbolic method's final worst error, and the
error it levels off at (its floor).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: the floor is the median worst error over this last fraction of a run's iterates
FLOOR_FRACTION = 0.1
#: a curve has flattened when the worst error falls by less than this fraction over a tenth of
#: its iterates, on a least-squares line through log(worst error) over the last FLAT_WINDOW of them
#: (a line, not two window medians: the noise of a noisy baseline's iterates cancels in the fit)
FLAT_DROP = 0.1
FLAT_WINDOW = 0.3


@dataclass(frozen=True)
class ErrorCurve:
    """Per iterate of one run: ``time_s``, ``renders``, ``worst`` and ``mean`` |error|."""

    time_s: np.ndarray
    renders: np.ndarray
    worst: np.ndarray
    mean: np.ndarray

    def __len__(self) -> int:
        return len(self.time_s)

    def time_to_reach(self, target: float) -> float | None:
        """The first time the worst error is at most ``target``; None if it never is."""
        hit = np.flatnonzero(self.worst <= target)
        return float(self.time_s[hit[0]]) if hit.size else None

    def renders_to_reach(self, target: float) -> int | None:
        hit = np.flatnonzero(self.worst <= target)
        return int(self.renders[hit[0]]) if hit.size else None

    @property
    def floor(self) -> float:
        """The median worst error over the last :data:`FLOOR_FRACTION` of the iterates."""
        tail = max(1, int(np.ceil(FLOOR_FRACTION * len(self))))
        return float(np.median(self.worst[-tail:]))

    @property
    def drop_per_tenth(self) -> float:
        """How much the worst error still falls over a tenth of the iterates: ``1 - exp(0.1 s)``
        with ``s`` the slope of a least-squares line through ``log(worst)`` against the iterate's
        position (0 to 1) over the last :data:`FLAT_WINDOW` of them; negative when it rises, NaN
        with fewer than 5 iterates there."""
        n = int(np.ceil(FLAT_WINDOW * len(self)))
        if n < 5:
            return float("nan")
        position = np.arange(len(self) - n, len(self)) / len(self)
        slope = np.polyfit(position, np.log(np.maximum(self.worst[-n:], 1e-300)), 1)[0]
        return float(1.0 - np.exp(0.1 * slope))

    @property
    def flattened(self) -> bool:
        """Whether the curve has levelled off: :attr:`drop_per_tenth` at most :data:`FLAT_DROP`
        (False when unknown)."""
        drop = self.drop_per_tenth
        return bool(np.isfinite(drop) and drop <= FLAT_DROP)


def _references(results: dict, only) -> np.ndarray:
    """(P, C) references of the run's parameters, NaN where unknown or not in ``only``."""
    C = len(results["channels"])
    out = np.full((len(results["parameters"]), C), np.nan)
    for i, p in enumerate(results["parameters"]):
        ref = p.get("reference")
        if ref is not None and (only is None or (str(p["segment"]), str(p["kernel"])) in only):
            out[i] = [np.nan if v is None else float(v) for v in ref]
    return out


def observable_set(runs: list[dict]) -> set[tuple[str, str]]:
    """(segment, kernel) of the parameters with a finite final estimate in every run of ``runs``:
    the set errors are compared on (a method cannot be faulted for what no view constrains)."""
    sets = [{(str(p["segment"]), str(p["kernel"])) for p in res["parameters"]
             if p.get("estimate") is not None and all(v is not None for v in p["estimate"])} for res in runs]
    return set.intersection(*sets) if sets else set()


def error_curve(results: dict, only: set | None = None) -> ErrorCurve | None:
    """The run's :class:`ErrorCurve` over the parameters in ``only`` ((segment, kernel) pairs;
    default all); None without a trace or without any reference."""
    trace = results.get("trace") or []
    if not trace:
        return None
    ref = _references(results, only)
    if not np.isfinite(ref).any():
        return None
    rows = []
    for entry in trace:
        est = np.array([[np.nan if v is None else v for v in row] for row in entry["estimate"]], dtype=float)
        err = np.abs(est - ref)
        err = err[np.isfinite(err)]
        if err.size:
            rows.append((entry["time_s"], entry["renders"], err.max(), err.mean()))
    if not rows:
        return None
    t, r, worst, mean = (np.array(col, dtype=float) for col in zip(*rows))
    return ErrorCurve(t, r.astype(int), worst, mean)


def equal_error_rows(curves: dict[str, list[ErrorCurve]], baseline: str) -> list[dict]:
    """Per method other than ``baseline``: the time and renders it needs to reach the median
    final worst error of the ``baseline`` runs (median over its runs that reach it), how many
    of its runs reach it, its floor (median over runs), and its time relative to the baseline's
    median final time."""
    base = curves.get(baseline) or []
    if not base:
        return []
    target = float(np.median([c.worst[-1] for c in base]))
    base_time = float(np.median([c.time_s[-1] for c in base]))
    rows = []
    for method, runs in curves.items():
        if method == baseline or not runs:
            continue
        times = [c.time_to_reach(target) for c in runs]
        reached = [t for t in times if t is not None]
        renders = [c.renders_to_reach(target) for c in runs if c.renders_to_reach(target) is not None]
        rows.append({"method": method, "target": target, "runs": len(runs), "reached": len(reached),
                     "time_s": float(np.median(reached)) if reached else None,
                     "renders": int(np.median(renders)) if renders else None,
                     "ratio": float(np.median(reached)) / base_time if reached and base_time > 0 else None,
                     "floor": float(np.median([c.floor for c in runs])),
                     "drop_per_tenth": float(np.median([c.drop_per_tenth for c in runs])),
                     "flattened": all(c.flattened for c in runs),
                     "max_time_s": float(max(c.time_s[-1] for c in runs)),
                     "max_renders": int(max(c.renders[-1] for c in runs))})
    return rows
