"""What the model does not explain, and how the fit keeps it out. In: a pass's prediction against the
observations (each view's image, coefficients and segment map). Out: per-pixel robust weights
(:mod:`~methods.symbolic.misfit.robust_scale`, :mod:`~methods.symbolic.misfit.robust_weights`;
the views' disagreement, :mod:`~methods.symbolic.misfit.consistency`), the clusters of correlated
residuals the cluster std sums over (:mod:`~methods.symbolic.misfit.clusters`), and each view's
camera registered to the prediction (:mod:`~methods.symbolic.misfit.registration` on the geometry
of :mod:`~methods.symbolic.misfit.turned_camera`; over the passes
:mod:`~methods.symbolic.misfit.alignment`, which hands the poses' covariance to the std). It stands
on the system and the trace, not on survey.
"""
