"""The scene model: plain, immutable numpy data (picklable, so worker processes can build their
own Mitsuba scenes). :func:`framework.scene.load.load_scene` builds it from a scene folder
(``docs/scene-format.md``)."""
from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from framework.errors import SceneError
from framework.brdf_kernels import canonical

CHANNELS = {"rgb": ("R", "G", "B"), "mono": ("Y",)}


@dataclass(frozen=True)
class Parameter:
    """One unknown of the inversion: the weight of ``kernel`` on segment ``segment`` (per channel)."""

    index: int          # position in the parameter vector ρ
    segment: int        # index into Scene.segments
    segment_name: str
    kernel: str


@dataclass(frozen=True)
class Segment:
    """A region of homogeneous reflectance: ``kernels`` weighted by one ρ per kernel and channel."""

    name: str
    meshes: tuple[str, ...]
    kernels: tuple[str, ...]
    reference: dict[str, np.ndarray] | None = None   # kernel -> (C,), where given
    #: kernel -> (C,): weights held at these values (a calibration panel), ``known:`` in
    #: scene.yaml; None when the segment has none. Checked: each a kernel of ``kernels``, in [0, 1],
    #: and with ``reference``'s other kernels Σ ≤ 1 per channel (where both give a kernel, equal)
    known: dict[str, np.ndarray] | None = None


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh; ``segment`` is None for a mesh that only emits."""

    path: str                      # as scene.yaml writes it: relative to the scene directory, or absolute
    vertices: np.ndarray           # (V, 3) float64, metres, +z up
    faces: np.ndarray              # (F, 3) int32
    segment: int | None
    radiance: np.ndarray | None = None   # (C,) if the mesh is an area emitter
    emitter: int | None = None           # its area emitter's index in Scene.emitters, if any

    @property
    def area(self) -> float:
        a, b, c = (self.vertices[self.faces[:, i]] for i in range(3))
        return float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())


@dataclass(frozen=True)
class Emitter:
    """Illumination: ``envmap`` (image (H,W,C), scale), ``constant`` (radiance),
    ``directional`` (direction the light travels, irradiance) or ``area`` (its meshes carry it).

    A scene.yaml ``scale`` given as a number is already applied: it is the envmap's ``scale``,
    and it multiplies the ``radiance`` or ``irradiance`` of the other types (their ``scale`` is
    1). A ``sunsky`` of scene.yaml becomes two emitters, its sky (``envmap``, ``part="sky"``,
    ``scale`` = its ``sky_scale``) and its sun (``directional``, ``part="sun"``, ``sun_scale``
    applied), both with the sunsky's ``source``.
    """

    type: str
    radiance: np.ndarray | None = None       # constant
    image: np.ndarray | None = None          # envmap, (H, W, C)
    scale: float = 1.0                       # envmap
    direction: np.ndarray | None = None      # directional, unit
    irradiance: np.ndarray | None = None     # directional
    file: str | None = None                  # envmap source, relative; None for a baked sunsky sky
    #: ``scale: unknown`` (or ``sun_scale``/``sky_scale: unknown`` for this part of a sunsky): one
    #: unknown factor per channel multiplies this emitter's light as given here (the nominal value)
    scale_unknown: bool = False
    source: int | None = None                # index of the emitter in scene.yaml's ``emitters``
    part: str | None = None                  # "sun" | "sky" for the parts of a ``sunsky``, else None


@dataclass(frozen=True)
class Light:
    """A light of scene.yaml ``lights``: the photographs of ``views`` were taken under
    ``emitters`` instead of the scene's ``emitters`` (another hour, another day)."""

    name: str
    views: tuple[str, ...]
    emitters: tuple[Emitter, ...]


#: Why a pixel is left out of a fit, by code (the index): the scene's (``mask``, ``saturated``: an
#: encoded value at the saturation limit or a code 0, ``outside``: outside the delivered image after
#: undistortion) and the fit's (``boundary``: on a material boundary, ``inconsistent``: its
#: observation disagrees with the other views of the same surface point, ``outlier``: its residual
#: is beyond the noise). Code 0 is a pixel the fit used.
EXCLUSION_REASONS = ("used", "mask", "saturated", "outside", "boundary", "inconsistent", "outlier")


@dataclass(frozen=True)
class Camera:
    """A pinhole camera of the COLMAP model: ``cam_from_world`` (3, 4), x right, y down, z forward.

    This is the camera the renderer uses: square pixels, focal length ``f``. Where the
    photographs came from another camera of the same pose (a distorted COLMAP model, or
    ``fx != fy``), ``distortion`` records that delivered camera and the loader has resampled
    the photographs onto this one (:mod:`framework.scene.undistort`).
    """

    name: str
    width: int
    height: int
    f: float
    cx: float
    cy: float
    cam_from_world: np.ndarray
    #: the camera that took the photographs, where it is not this pinhole: (COLMAP model name,
    #: its parameters in COLMAP's order), e.g. ``("OPENCV", (fx, fy, cx, cy, k1, k2, p1, p2))``;
    #: None for a pinhole camera with fx == fy (the photographs are used as they are)
    distortion: tuple[str, tuple[float, ...]] | None = None
    #: the COLMAP camera id of ``cameras.txt`` this view uses (views sharing one share their lens:
    #: one vignetting profile); None for a camera built without a COLMAP model
    camera_id: int | None = field(default=None, compare=False)

    def project(self, points: np.ndarray) -> np.ndarray:
        """Pixel coordinates (x right, y down, pixel centres at .5) of world points (N, 3)."""
        pc = points @ self.cam_from_world[:, :3].T + self.cam_from_world[:, 3]
        return np.stack([self.f * pc[:, 0] / pc[:, 2] + self.cx,
                         self.f * pc[:, 1] / pc[:, 2] + self.cy], axis=1)

    def pinhole(self):
        """This camera as a ``pycolmap.Camera`` (``PINHOLE``, fx = fy = f)."""
        import pycolmap
        return pycolmap.Camera(model="PINHOLE", width=int(self.width), height=int(self.height),
                               params=[self.f, self.f, self.cx, self.cy])

    def delivered(self):
        """The camera that took the photographs, as a ``pycolmap.Camera``: ``distortion``'s
        model and parameters, or :meth:`pinhole` where ``distortion`` is None."""
        if self.distortion is None:
            return self.pinhole()
        import pycolmap
        model, params = self.distortion
        return pycolmap.Camera(model=model, width=int(self.width), height=int(self.height),
                               params=[float(x) for x in params])


@dataclass(frozen=True)
class Photometry:
    """How the photographs encode radiance (scene.yaml ``photometry``, ``docs/scene-format.md``)."""

    encoding: str | None = None          # "linear" | "srgb" as declared; None: by file type
    exposure: str = "known"              # "known": pixel = radiance; "per_view": one gain per view, channel
    reference_view: str | None = None    # with "per_view": the view whose gains are 1
    saturation: float | None = None      # as declared; None: 0.99 for 8/16-bit files, none for EXR
    #: "none": no lens falloff; "estimate": per camera, pixel = (1 + a1 r^2 + a2 r^4 + a3 r^6) ·
    #: radiance with a_i unknown (r = distance from the principal point / half the image
    #: diagonal); "known": that profile with ``vignetting_profile``'s coefficients
    vignetting: str = "none"
    vignetting_profile: tuple[float, float, float] | None = None   # (a1, a2, a3) with "known"
    #: interpolation of a distorted photograph onto its pinhole camera: "bilinear" or "cubic"
    #: (:class:`framework.scene.undistort.Resampling`)
    resampling: str = "bilinear"


@dataclass(frozen=True)
class Scene:
    name: str
    root: Path
    channels: tuple[str, ...]
    segments: tuple[Segment, ...]
    meshes: tuple[Mesh, ...]
    emitters: tuple[Emitter, ...]
    cameras: tuple[Camera, ...]               # sorted by name
    images: dict[str, np.ndarray] | None      # camera name -> (H, W, C) linear; None: synthesise
    content_hash: str = field(default="", compare=False)   # of every file read (load._content_hash)
    #: the COLMAP file the camera poses came from, relative to ``root``: ``sparse/frames.txt``
    #: when the model has rigs and frames (pycolmap then ignores the poses of images.txt),
    #: ``sparse/images.txt`` otherwise (or their ``.bin`` twins)
    pose_source: str = field(default="", compare=False)
    #: view -> (H, W) float32: 1 = use the pixel, 0 = ignore it (masked, saturated, black-clipped,
    #: outside the delivered image after undistortion); None when every pixel of every view is usable
    weights: dict[str, np.ndarray] | None = field(default=None, compare=False)
    #: view -> (H, W) uint8: why a pixel of weight 0 is unusable, an index into
    #: :data:`EXCLUSION_REASONS` (0: usable); None when every pixel of every view is usable
    excluded: dict[str, np.ndarray] | None = field(default=None, compare=False)
    #: view -> (H, W, C) float32: the standard deviation of the quantisation of the delivered
    #: 8/16-bit encoding, in linear units (0 for an EXR view); None when no view is integer-coded
    noise: dict[str, np.ndarray] | None = field(default=None, compare=False)
    photometry: Photometry = field(default_factory=Photometry)
    #: scene.yaml ``origin``: the survey coordinates (a national grid, CityJSON's) of the local
    #: (0, 0, 0) the meshes and cameras are given in; None when the scene names none
    origin: tuple[float, float, float] | None = field(default=None, compare=False)
    #: scene.yaml ``lights``: the other lights, each with the views photographed under it; every
    #: view they do not name is lit by ``emitters`` (:meth:`light_of`)
    lights: tuple[Light, ...] = field(default=(), compare=False)
    #: the light ``emitters`` are: None for scene.yaml's ``emitters``, a name of ``lights`` for a
    #: scene from :meth:`under`
    light: str | None = field(default=None, compare=False)

    def light_of(self, view: str) -> str | None:
        """The name of the light view ``view`` was photographed under: a name of ``lights``, or
        None for scene.yaml's ``emitters``."""
        return next((light.name for light in self.lights if view in light.views), None)

    def lit_by(self, light: str | None) -> list[Camera]:
        """The cameras of the views photographed under ``light`` (:meth:`light_of`), by name."""
        return [c for c in self.cameras if self.light_of(c.name) == light]

    def under(self, light: str | None) -> Scene:
        """This scene lit by ``light``: its emitters in place of ``emitters`` (``light`` set, the
        content hash changed with it); None or the scene's own light: the scene itself."""
        if light == self.light:
            return self
        if self.light is not None:
            raise ValueError(f"scene under light '{self.light}': relight the scene as loaded")
        found = next((x for x in self.lights if x.name == light), None)
        if found is None:
            raise ValueError(f"scene {self.name} has no light '{light}' (its lights: "
                             f"{', '.join(x.name for x in self.lights) or 'none'})")
        digest = hashlib.sha256(f"{self.content_hash}/light/{light}".encode()).hexdigest()[:16]
        return dataclasses.replace(self, emitters=found.emitters, light=light, content_hash=digest)

    def parameters(self, *, kernels: tuple[str, ...] | None = None):
        """The unknowns (segment, kernel) in segment order; ``kernels`` (canonical names,
        :func:`framework.brdf_kernels.canonical`) restricts the kernel set."""
        out = []
        for s, seg in enumerate(self.segments):
            for k in seg.kernels:
                if kernels is None or canonical(k) in kernels:
                    out.append(Parameter(len(out), s, seg.name, k))
        return out

    def reference(self, parameters) -> np.ndarray:
        """(P, C) reference weights of ``parameters``; NaN where no reference is known.

        A kernel the parameter list leaves out of a segment does not change the others'
        references: the Lambertian setting compares ρ_d with the true ρ_d (paper Table 1).
        A ``known`` weight is its own reference where ``reference`` does not give it (the
        schema checks that they agree where both do).
        """
        ref = np.full((len(parameters), len(self.channels)), np.nan)
        for i, p in enumerate(parameters):
            seg = self.segments[p.segment]
            for given in (seg.reference, seg.known):
                if given is not None and p.kernel in given:
                    ref[i] = given[p.kernel]
                    break
        return ref

    def camera(self, name: str) -> Camera:
        for c in self.cameras:
            if c.name == name:
                return c
        raise SceneError(f"view '{name}' is not an image of {self.root / 'sparse'}; "
                         f"choose among: {', '.join(c.name for c in self.cameras)}")
