"""Section 4: the paper's Tables 1 and 2 (Coubard et al., section 5) next to our estimates.

Runs on ``urban_canyon_mono`` (the paper's 550 nm band; its references are Table 2's):
lambertian_prior and symbolic on the single default view, symbolic on all views.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

from bench.compare import run_one, warm_observations

#: Table 1 (Lambertian): object -> (reference albedo, estimated, error)
TABLE1 = {"roof": (0.2, 0.285, 0.085), "wall": (0.8, 0.761, -0.039), "balcony": (0.3, 0.291, -0.009),
          "asphalt": (0.2, 0.201, 0.001), "awning": (0.05, 0.0496, -0.0004), "window": (0.9, 0.230, -0.670)}
#: Table 2 (Lambertian + specular): (object, kernel) -> (reference, estimated, error); None: not given
TABLE2 = {("roof", "diffuse"): (0.2, 0.390, 0.190), ("roof", "specular"): None,
          ("wall", "diffuse"): (0.72, 0.762, 0.042), ("wall", "specular"): (0.08, 0.326, 0.246),
          ("balcony", "diffuse"): (0.3, 0.284, -0.016), ("balcony", "specular"): (0.0, 0.373, 0.373),
          ("asphalt", "diffuse"): (0.2, 0.218, 0.018), ("asphalt", "specular"): (0.0, 0.000, 0.000),
          ("awning", "diffuse"): (0.05, 0.046, -0.004), ("awning", "specular"): (0.0, 0.300, 0.300),
          ("window", "diffuse"): (0.18, 0.185, 0.005), ("window", "specular"): (0.72, 0.494, -0.226)}
PAPER_TOTAL_MIN = 20.0     # "about 20 min" for symbolic ray tracing + minimisation, 200x200
TARGET = {"diffuse": 0.02, "specular": 0.03}   # multi-view target on |error|

#: the paper's algorithm is the ``symbolic_paper`` preset (one truncated pass); the default
#: ``symbolic`` (tail and refinement) is the last row
RUNS = [("lambertian_prior", ["method=lambertian_prior", "method.tail_bounces=0", "method.refine=0", "method.cost=joint"], 1),
        ("symbolic", ["method=symbolic_paper"], 1), ("symbolic", ["method=symbolic_paper"], 0),
        ("symbolic (default: tail 4, refine)", ["method=symbolic"], 0)]


def run(sizes, root: Path, log=print) -> list[dict]:
    """The mono runs (row dicts as :func:`bench.compare.run_one`), every view at the scene's own
    200x200 (the paper's size; the comparison section's all-views runs shrink theirs)."""
    sizes = dataclasses.replace(sizes, cmp_all_image=None)
    rows = []
    for n_views in (1, 0):
        warm_observations(sizes, root, "urban_canyon_mono", n_views)
    for label, overrides, n_views in RUNS:
        rows.append(run_one(sizes, root, label, "urban_canyon_mono", n_views, overrides, sizes.cmp_budget, log))
    return rows
