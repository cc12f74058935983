"""Which kernel weights the pixels determine, and how well. In: the pass's Gram system and basis,
the estimate, and each view's coefficients, pixels and pixel weights. Out: the observable
parameters and the system restricted to them (:mod:`~methods.symbolic.uncertainty.observability`),
the covariance of the cost's gradient from every pixel's score, by pixel or by cluster, with the
registered cameras' pose uncertainty (:mod:`~methods.symbolic.uncertainty.sandwich_meat`), and the
standard errors, correlations and ill-determined flags from the exact Hessian of the cost
(:mod:`~methods.symbolic.uncertainty.standard_errors`). It uses misfit's clusters (their CR1
factor), never the fits.
"""
