"""Where a run's time went, and the caption of a view's pixel-weight image: pieces of the run
report (:mod:`reports.run`) that read results.json's ``timings_s`` / ``solve_stages_s`` and a
view's weights (docs/results.md)."""

from __future__ import annotations

import numpy as np

from reports.data import fmt_num
from reports.doc import Doc

#: ``(solve_stages_s key, label)`` of the parts of the symbolic method's solve, in report order
#: (the stages are disjoint and add up to ``timings_s.solve``; docs/results.md)
SOLVE_PARTS = (("known", "known weights substituted into the Gram system (a calibration panel)"),
               ("psd", "projection of the Gram matrices (PSD)"),
               ("solver", "solver"),
               ("uncertainty", "standard errors (the sandwich)"),
               ("field_setup", "photographs: pixel weights, gains' and lens' coefficients"),
               ("weighted_systems", "photographs: each robust round's Gram system"),
               ("robust_weights", "photographs: robust reweighting"),
               ("fit_quality", "photographs: how well the model explains each material"),
               ("registration", "registration of the views (method.align)"),
               ("bias_refits", "finite-spp bias correction: the half-spp refits (method.bias)"),
               ("other", "other parts of the solve"))


def time_rows(res: dict) -> list[tuple[str, float]]:
    """``(what, seconds)`` of the method's wall time, by part: the polynomial passes (or, for a
    baseline, its renders), the stages of the solve (:data:`SOLVE_PARTS`; a baseline's solve as
    one row), and the rest; empty when results.json holds no method or total time."""
    timings = res.get("timings_s") if isinstance(res.get("timings_s"), dict) else {}
    stages = res.get("solve_stages_s") if isinstance(res.get("solve_stages_s"), dict) else {}
    whole = timings.get("method", timings.get("total"))
    if not isinstance(whole, (int, float)):
        return []
    rows = [("renders (the polynomial passes)" if stages else "renders", float(timings.get("render") or 0.0))]
    if stages:
        rows += [(label, float(stages[key])) for key, label in SOLVE_PARTS
                 if isinstance(stages.get(key), (int, float)) and stages[key] > 0]
    else:
        rows.append(("solve", float(timings.get("solve") or 0.0)))
    rest = float(whole) - sum(t for _, t in rows)
    rows.append(("outside the passes and the solve: prior, reconstructions, relighting, bookkeeping", max(rest, 0.0)))
    return rows


def section_time_spent(doc: Doc, res: dict) -> None:
    """A table of :func:`time_rows` with each part's share, and where the cost evaluations of
    the convergence plot lie in it."""
    rows = time_rows(res)
    if not rows:
        return
    whole = sum(t for _, t in rows)
    doc.heading("Where the time went", level=3)
    doc.table(["Part", "Seconds", "Share"],
              [(what, fmt_num(t, digits=2), f"{100 * t / whole:.0f} %" if whole > 0 else "–") for what, t in rows])
    times = [t for t in (res.get("cost_times_s") or []) if isinstance(t, (int, float))]
    if len(times) > 1:
        doc.para(f"The convergence plot's cost evaluations span {fmt_num(times[0], digits=1)}–"
                 f"{fmt_num(times[-1], digits=1)} s after the method started ({fmt_num(times[-1] - times[0], digits=2)}"
                 " s): the last solve's evaluations; the table shows where the rest went.", note=True)


def weights_caption(weights: np.ndarray) -> str:
    """The caption of a view's pixel-weight image (white 1, black 0): says so when every pixel
    had weight 1, where the image is plain white."""
    w = np.asarray(weights, float)
    if w.size and np.all(w == 1.0):
        return "pixel weight in the fit: every pixel had weight 1 (a plain white image)"
    return ("pixel weight in the fit, black 0 (ignored or outlier) to white 1; here "
            f"{fmt_num(float(w.min()), digits=3)} "
            f"to {fmt_num(float(w.max()), digits=3)}, median {fmt_num(float(np.median(w)), digits=3)}")
