"""The experiment framework: configuration and run orchestration (``config``, ``experiment``,
``run``), the method interface (``registry``), scene folders (``scene/``), Mitsuba rendering
(``render/``), run outputs (``results``, ``observe``, ``relight``) and utilities.

Importing the package points Dr.Jit at a usable libLLVM (``DRJIT_LIBLLVM_PATH``) before any
module imports Dr.Jit, which reads it once at import and aborts the process with libLLVM 15.
"""
from framework.render.backend import point_at_libllvm

point_at_libllvm()
