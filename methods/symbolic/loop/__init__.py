"""The passes of one run and the method's result. In: the problem, the parameters, the start and the
method's options. Out: the :class:`~framework.registry.MethodResult` of the last pass's fit
(:mod:`~methods.symbolic.loop.outputs`), after further passes rendered at the estimate until it
stops moving, the views aligned between passes (:mod:`~methods.symbolic.loop.refinement`), and the
finite-spp bias removed by extrapolation from the last pass's half-spp fits
(:mod:`~methods.symbolic.loop.richardson`). The top stage: only the method's registration
(:mod:`methods.symbolic`) imports it.
"""
