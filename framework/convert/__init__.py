"""Convert a labelled mesh or a city model into a scene folder: ``python -m framework.convert``.

One reader per format (:mod:`.obj`, :mod:`.gltf`, :mod:`.ply`, :mod:`.cityjson`) fills the common
segment model (:mod:`.model`: float64 vertices, triangles and polygons with holes per segment);
:mod:`.model` triangulates (mapbox earcut) and moves survey coordinates to a local origin;
:func:`.convert.convert` writes the folder through :mod:`framework.scene.write` and checks it.
The command line and its options are in ``docs/convert.md``.
"""
from framework.convert.convert import Conversion, convert

__all__ = ["Conversion", "convert"]
