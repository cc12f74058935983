"""Fake run folders for the report tests (no rendering): known numbers, 32x32 EXRs.

The report test modules import ``make_fake_run``, ``report_error_of`` and the REPORT_*
constants from here; the ``fake_sweep`` fixture (conftest.py) is built with ``make_fake_sweep``.
"""
import json
from pathlib import Path

import numpy as np

REPORT_REFS = {("wall", "diffuse"): [0.72, 0.70, 0.68], ("wall", "specular"): [0.08, 0.08, 0.08],
               ("asphalt", "diffuse"): [0.20, 0.19, 0.18]}
REPORT_METHODS = {"symbolic": {"offset": 0.01, "total": 2.0, "renders": 1},
                  "iterative": {"offset": -0.02, "total": 10.0, "renders": 50}}
REPORT_SEEDS = (0, 1, 2)
RECON_OFFSET = 0.05


def report_error_of(method: str, seed: int, channel: int) -> float:
    """The error written for every parameter of a fake run (known to the tests)."""
    return REPORT_METHODS[method]["offset"] * (seed + 1) * (1 + channel)


def _write_images(run: Path, size: int, channels, seed: int) -> None:
    """Observed (seeded noise), reconstruction (observed + offset) and a segment map."""
    from framework.images import write_exr

    (run / "images").mkdir(parents=True, exist_ok=True)
    obs = np.random.default_rng(seed).uniform(0.1, 1.0, (size, size, len(channels)))
    write_exr(run / "images/v0.png.observed.exr", obs.astype(np.float32), channels)
    write_exr(run / "images/v0.png.reconstruction.exr", (obs + RECON_OFFSET).astype(np.float32),
              channels)
    seg = np.zeros((size, size), np.int32)
    seg[:, size // 2:] = 1
    seg[: size // 4] = -1
    np.save(run / "images/v0.png.segments.npy", seg)


def _parameters(method: str, seed: int, nc: int) -> list:
    """Parameter rows with errors from ``report_error_of``."""
    params = []
    for (segment, kernel), ref in REPORT_REFS.items():
        ref = ref[:nc]
        err = [report_error_of(method, seed, c) for c in range(nc)]
        params.append({"segment": segment, "kernel": kernel, "reference": ref,
                       "estimate": [r + e for r, e in zip(ref, err)], "error": err,
                       "std": [0.001] * nc})
    return params


def make_fake_run(root, *, method: str = "symbolic", seed: int = 0, size: int = 32,
                  channels=("R", "G", "B"), correlation: bool = True) -> Path:
    """Write a run folder (results.json, EXRs, segment map) with known numbers."""
    run = Path(root)
    _write_images(run, size, channels, seed)
    m = REPORT_METHODS[method]
    costs = [10.0 / (i + 1) ** 2 for i in range(8)]
    results = {
        "method": method, "scene": "courtyard", "channels": list(channels),
        "parameters": _parameters(method, seed, len(channels)),
        "timings_s": {"render": m["total"] * 0.9 + seed, "solve": m["total"] * 0.1,
                      "total": m["total"] + seed},
        "renders": m["renders"], "cost_history": costs, "cost_times_s": [0.1] * len(costs),
        "image_rmse": RECON_OFFSET,
        "settings": {"spp": 16, "max_bounces": 3, "seed": seed, "variant": "scalar_rgb",
                     "views": ["v0.png"]},
        "views": [{"name": "v0.png", "observed": "images/v0.png.observed.exr",
                   "reconstruction": "images/v0.png.reconstruction.exr",
                   "segments": "images/v0.png.segments.npy"}],
        "segments": ["wall", "asphalt"],
        "correlation": {"labels": ["wall ρ_d", "wall ρ_s", "asphalt ρ_d"],
                        "matrix": [[1, -0.8, 0.1], [-0.8, 1, 0.0], [0.1, 0.0, 1]]}
        if correlation else None,
        "relit": [{"name": "relit noon", "image": "images/v0.png.observed.exr"}],
    }
    (run / "results.json").write_text(json.dumps(results, indent=2))
    return run


def make_fake_sweep(sweep) -> Path:
    """A sweep folder with 2 methods x 3 seeds of fake runs."""
    sweep = Path(sweep)
    for method in REPORT_METHODS:
        for seed in REPORT_SEEDS:
            make_fake_run(sweep / f"{method}_seed{seed}", method=method, seed=seed)
    return sweep
