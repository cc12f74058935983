"""Benchmark of the toolkit: ``python -m bench [--quick] [--out BENCHMARKS.md]``.

Sections (all measured in one process on one machine, at equal spp):

1. :mod:`bench.render_ratio` -- symbolic polynomial pass vs a plain Mitsuba ``path`` render.
2. :mod:`bench.memory` -- peak memory of the symbolic method at 1, 4 and all views (subprocesses).
3. :mod:`bench.compare` -- method comparison (time, renders, errors) via ``run_experiment``.
4. :mod:`bench.paper` -- single-view estimates next to the paper's Tables 1 and 2.
"""
