"""The device side of the polynomial pass: paths traced tile by tile as Dr.Jit kernels, each pixel
kept as a polynomial in the kernel weights (paper eq. 7-8). In: a Mitsuba scene and sensor, the
segments' kernels with the guesses that set their selection probabilities
(:class:`~methods.symbolic.trace.integrator_tables.KernelTables`), spp, seed and the pixel
footprint. Out: a view's coefficients, one sparse matrix per channel (and per half, or quarter, of
the samples) over the multiset codes of the monomials that occur
(:mod:`~methods.symbolic.trace.monomial_codes`), from
:meth:`~methods.symbolic.trace.integrator_tiles.CoefficientTiles.coefficients_halves` (or
``coefficients_sparse``), which the host's pass calls. The one boundary to the host is each tile's
hand-over in ``CoefficientTiles._tile``:
:func:`~methods.symbolic.trace.pixel_sums.pixel_sums` copies the tile's per-pixel sums out of the
device (the host maps the tile's few distinct path keys to columns on the way), or, for a key range
too wide for its table, :meth:`~methods.symbolic.trace.events.EventBuffer.compact` copies out the
compacted events, summed on the host. The trace imports nothing of the stages above it.
"""
