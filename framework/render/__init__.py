"""Mitsuba rendering of the scene model: the variant and libLLVM set-up (:mod:`.backend`), the
exact kernel-sum BSDF (:mod:`.kernel_bsdf`), environment map conventions (:mod:`.envmap`) and
the one builder from a scene model and weights ρ to a Mitsuba scene (:mod:`.mitsuba_scene`).

Importing this package points Dr.Jit at a usable libLLVM (``DRJIT_LIBLLVM_PATH``) before any of
its modules imports Dr.Jit: Dr.Jit 1.5 aborts the process with libLLVM 15.
"""
from framework.render.backend import point_at_libllvm

point_at_libllvm()
