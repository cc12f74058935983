"""The inversion methods, one folder each, registered by name (:mod:`framework.registry`).

``import framework`` first: it points Dr.Jit at a usable libLLVM before a method imports Dr.Jit.
"""
import framework  # noqa: F401
