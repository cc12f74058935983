"""The fits of one pass, with no more rendering. In: the pass's summed Gram system and basis (or,
on the field path, its per-view coefficients), the parameters with their start, and each view's
coefficients and observed pixels. Out: a :class:`~methods.symbolic.fit.fit.Fit`, the estimate, its
std and what the run reports of it: the joint cost of every pixel
(:mod:`~methods.symbolic.fit.joint`, the paper's eq. 6) or each segment's own pixels
(:mod:`~methods.symbolic.fit.per_segment`), minimised by :mod:`~methods.symbolic.fit.solve`, with
the known weights substituted (:mod:`~methods.symbolic.fit.with_known`); for photographs the field
path around either (:mod:`~methods.symbolic.fit.field`: pixel weights, exposure gains, vignetting,
emitter scales, robust rounds) and how well the model explains each material
(:mod:`~methods.symbolic.fit.fit_quality`). The fits call the stages below them: uncertainty (the
std), misfit (robust weights, clusters, the poses' terms) and survey.
"""
