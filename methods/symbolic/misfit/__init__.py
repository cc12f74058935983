"""Stage ``misfit`` of the symbolic method (see methods/symbolic/__init__.py)."""
