"""Scene folders: the model (:mod:`.model`), the reader (:mod:`.load`) with the schema of
scene.yaml (:mod:`.schema`) and the COLMAP reader (:mod:`.colmap`), the writer that scene
builders use (:mod:`.write`), checked image input (:mod:`.exr`) and the field photographs
(:mod:`.photos`: PNG, JPEG, EXR and masks, resampled by :mod:`.undistort`).

The format is documented in ``docs/scene-format.md``.
"""
from framework.scene.load import image_file, load_scene
from framework.scene.model import CHANNELS, Camera, Emitter, Light, Mesh, Parameter, Photometry, Scene, Segment

__all__ = ["CHANNELS", "Camera", "Emitter", "Light", "Mesh", "Parameter", "Photometry", "Scene", "Segment", "image_file",
           "load_scene"]
