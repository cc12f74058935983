"""Error against time from results.json ``trace`` (reports/convergence.py), on hand-made traces."""
from __future__ import annotations

import numpy as np
import pytest

from reports.convergence import FLAT_DROP, equal_error_rows, error_curve


def _results(method, trace, refs=((0.5, 0.5), (0.2, None))):
    return {"method": method, "channels": ["R", "G"],
            "parameters": [{"segment": f"s{i}", "kernel": "diffuse", "reference": list(r)} for i, r in enumerate(refs)],
            "trace": [{"time_s": t, "renders": n, "estimate": est} for t, n, est in trace]}


def test_error_curve_by_hand():
    """Errors over parameters x channels with a reference and a finite estimate:
    iterate 0: |0.4-0.5|, |0.5-0.5|, |0.1-0.2| -> worst 0.1, mean 0.2/3;
    iterate 1: the second parameter unobservable (None): 0.05, 0.0 -> worst 0.05, mean 0.025."""
    res = _results("m", [(0.0, 1, [[0.4, 0.5], [0.1, 0.9]]), (2.0, 1, [[0.45, 0.5], [None, None]])])
    c = error_curve(res)
    np.testing.assert_allclose(c.worst, [0.1, 0.05])
    np.testing.assert_allclose(c.mean, [0.2 / 3, 0.025])
    assert c.time_to_reach(0.06) == 2.0 and c.renders_to_reach(0.06) == 1
    assert c.time_to_reach(0.01) is None


def test_error_curve_without_trace_or_reference():
    assert error_curve({"channels": ["Y"], "parameters": [{"reference": [0.1]}], "trace": []}) is None
    res = _results("m", [(0.0, 1, [[0.4, 0.5], [0.1, 0.9]])], refs=((None, None), (None, None)))
    assert error_curve(res) is None


def test_equal_error_rows():
    """Target = symbolic's final worst (0.02); the baseline reaches it at t = 30 s (10 renders)
    in one of two runs; floor = median over runs of the median worst over the last 10 %."""
    sym = error_curve(_results("symbolic", [(1.0, 1, [[0.5, 0.5], [0.2, 0.0]]), (3.0, 1, [[0.52, 0.5], [0.2, 0.0]])]))
    slow = error_curve(_results("it", [(5.0, 2, [[0.3, 0.5], [0.2, 0.0]]), (30.0, 10, [[0.49, 0.5], [0.2, 0.0]])]))
    never = error_curve(_results("it", [(5.0, 2, [[0.3, 0.5], [0.2, 0.0]]), (40.0, 12, [[0.45, 0.5], [0.2, 0.0]])]))
    rows = equal_error_rows({"symbolic": [sym], "iterative": [slow, never]}, "symbolic")
    assert len(rows) == 1
    r = rows[0]
    assert r["target"] == pytest.approx(0.02)
    assert (r["reached"], r["runs"], r["time_s"], r["renders"]) == (1, 2, 30.0, 10)
    assert r["ratio"] == pytest.approx(10.0)
    assert r["floor"] == pytest.approx(np.median([0.01, 0.05]))
    assert (r["max_renders"], r["max_time_s"]) == (12, 40.0)


def test_flattened_by_hand():
    """20 iterates, the last 6 in the fit: a worst error falling by 0.9 per iterate falls by
    1 - 0.9² = 0.19 over a tenth (2 iterates): not flat; one alternating 0.1, 0.12 (noise around
    a level; the fitted line rises slightly, a negative drop) is flat, floor the median of the
    last 2, 0.11; with 4 iterates (fewer than 5 in the fit) it is unknown."""
    def curve(worst):
        return error_curve(_results("m", [(float(i), i, [[0.5 + w, 0.5], [0.2, 0.2]]) for i, w in enumerate(worst)],
                                    refs=((0.5, 0.5), (0.2, 0.2))))
    falling = curve(list(0.5 * 0.9 ** np.arange(20)))
    assert falling.drop_per_tenth == pytest.approx(1 - 0.9 ** 2) and not falling.flattened
    flat = curve([0.5] * 14 + [0.1, 0.12] * 3)
    assert abs(flat.drop_per_tenth) < FLAT_DROP and flat.flattened
    assert flat.floor == pytest.approx(0.11)
    short = curve([0.3, 0.2, 0.1, 0.1])
    assert np.isnan(short.drop_per_tenth) and not short.flattened
    rows = equal_error_rows({"symbolic": [short], "d": [flat]}, "symbolic")
    assert rows[0]["flattened"] and rows[0]["drop_per_tenth"] == pytest.approx(flat.drop_per_tenth)


def test_variant_labels_separate_variants_not_seeds():
    """Runs of one method that differ in an option are labelled apart (the most common value
    keeps the bare name); runs that differ only in their seed share a label."""
    from reports.compare import variant_labels

    def run(method, seed, **method_settings):
        return (None, {"method": method, "settings": {"seed": seed, "observe": {"spp": 8, "seed": seed},
                                                      "tail_bounces": 0,
                                                      "method_settings": {"name": method, **method_settings}}})
    runs = [run("symbolic", 0, init="guess"), run("symbolic", 1, init="guess"),
            run("symbolic", 0, init="lambertian_prior"), run("iterative", 0, noise="fresh"),
            run("iterative", 1, noise="fresh"), run("iterative", 0, noise="fixed")]
    assert variant_labels(runs) == ["symbolic", "symbolic", "symbolic (init=lambertian_prior)",
                                    "iterative", "iterative", "iterative (noise=fixed)"]
