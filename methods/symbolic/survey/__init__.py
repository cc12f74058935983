"""What a survey declares beyond the kernel weights (scene.yaml ``scale: unknown``, ``photometry``,
``known``), as parameters of the fit or values substituted into it. In: the scene's declarations
and the pass's coefficients, basis or Gram system. Out: the coefficients over the extra parameters
with the parameters, their starts and their reports: the emitters' unknown scales
(:mod:`~methods.symbolic.survey.illumination`), the per-view exposure gains
(:mod:`~methods.symbolic.survey.exposure`) and a lens's vignetting
(:mod:`~methods.symbolic.survey.vignetting`); and for known weights (a calibration panel) the
:class:`~methods.symbolic.survey.known.Substitution` that removes them from the system
(:mod:`~methods.symbolic.survey.known`). It stands on the system and the trace, not on misfit.
"""
