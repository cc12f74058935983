"""The host side of the polynomial pass: each view rendered once through the trace and turned into
the Gram system of the cost. In: the problem (scene, cameras, observed pixels), the parameters
and their guesses, and the pass's settings. Out: a
:class:`~methods.symbolic.system.coefficients.PassResult` (:mod:`~methods.symbolic.system.polynomial_pass`):
each view's coefficients (cached tile by tile, :mod:`~methods.symbolic.system.pass_cache`) and the
summed :class:`~methods.symbolic.system.gram.GramSystem` of ``μᵀGμ - 2bᵀμ + yy`` over the
monomials that occur (:mod:`~methods.symbolic.system.basis`; G stored as its upper triangle,
:mod:`~methods.symbolic.system.upper_triangle`; a view's system rebuilt from its coefficients with
pixel weights, :mod:`~methods.symbolic.system.view_systems`), and that cost as a function of ρ with
its exact gradient and Hessian (:mod:`~methods.symbolic.system.cost`). Which emitters the pass keeps
apart is :mod:`~methods.symbolic.system.emitter_groups`'.
"""
