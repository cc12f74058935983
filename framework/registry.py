"""The method interface and registry.

A method is one folder ``methods/<name>/`` whose ``__init__.py`` defines a :class:`Method`
subclass decorated with :func:`register`, plus one YAML ``framework/conf/method/<name>.yaml``
(its ``name`` key is the registry key, its other keys the defaults of the method's options,
generated from their fields by :mod:`framework.method_yaml`, or a preset's Hydra defaults list
and the defaults it changes). The method's ``Options`` is a frozen dataclass
(:mod:`framework.options`) whose fields hold each option's default and description: built once
from the config group, checked as it is built, and kept as ``self.options``.
"""
from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from framework.config import RunSettings
from framework.errors import ConfigError
from framework.scene.model import Parameter


@dataclass
class Problem:
    """Everything a method needs: the scene, the views to fit, their observed images, the settings.

    ``settings`` are the run-wide settings (:class:`framework.config.RunSettings`: spp,
    max_bounces, tail_bounces, seed, budget_renders, variant, executor, cache_dir, observe),
    checked once; a method's own options come to it as ``Method(options)``.
    """

    scene: Any                       # framework.scene.Scene
    cameras: list                    # framework.scene.Camera, the selected views
    observed: dict[str, np.ndarray]  # camera name -> (H, W, C) float32 linear radiance
    parameters: list[Parameter]
    settings: RunSettings = field(default_factory=RunSettings)
    #: camera name -> (H, W) pixel weights of the scene (0: ignore the pixel: masked, saturated,
    #: outside the delivered image); None: every pixel counts
    weights: dict[str, np.ndarray] | None = None
    #: selected views left out because they constrain no parameter (no usable pixel, only sky,
    #: unlit), name -> why; results.json ``views_left_out``
    views_left_out: dict[str, str] = field(default_factory=dict)
    #: camera name -> (k, k) covariance of the camera's rotation (pitch, yaw[, roll]) in pixels of
    #: image motion, for cameras a method registered to the model (``method.align``); a camera
    #: absent (or None) is taken as exact
    pose_covariance: dict[str, np.ndarray] | None = None
    #: the views of ``holdout=[...]`` (:class:`framework.holdout.HeldOut`): read and checked, never
    #: handed to the method's fit; None or empty when nothing is held out
    held_out: Any = None

    @property
    def seed(self) -> int:
        return self.settings.seed

    @property
    def n_channels(self) -> int:
        return len(self.scene.channels)


@dataclass
class MethodResult:
    """What a method returns; the framework turns it into results.json and the report."""

    estimate: np.ndarray                       # (P, C); NaN where a parameter is unobservable
    renders: int                               # full ray-tracing passes over the views
    timings_s: dict[str, float] = field(default_factory=dict)   # at least render, solve
    cost_history: list[float] = field(default_factory=list)     # cost at each evaluation
    cost_times_s: list[float] = field(default_factory=list)     # seconds since the method started
    reconstructions: dict[str, np.ndarray] = field(default_factory=dict)  # view -> (H, W, C)
    #: view -> (H, W, C) Monte Carlo variance of each reconstructed pixel, where the method knows it
    #: (the symbolic pass's two halves); None: unknown
    reconstruction_variance: dict[str, np.ndarray] | None = None
    std: np.ndarray | None = None              # (P, C) standard errors, where known
    observable: np.ndarray | None = None       # (P,) bool, where known
    extras: dict[str, Any] = field(default_factory=dict)        # method-specific, JSON-able
    parameters: list[Parameter] | None = None  # the unknowns estimated; None: problem.parameters
    #: view -> (H, W) weight of each pixel in the final fit (scene weights times robust ones)
    pixel_weights: dict[str, np.ndarray] | None = None
    #: view -> (H, W) uint8: why the fit left each pixel out, a code of
    #: ``framework.scene.model.EXCLUSION_REASONS`` (0: used); None: the scene's reasons only
    pixel_reasons: dict[str, np.ndarray] | None = None
    #: one entry per iterate: {"time_s": since the method started, "renders": spent so far,
    #: "estimate": (P, C) nested lists in ``parameters`` order, None where unobservable}
    trace: list[dict] = field(default_factory=list)


class Method(ABC):
    """Base class: ``Method(options).run(problem) -> MethodResult``.

    ``options`` is an instance of the class's ``Options`` dataclass, or the method's config group
    (``framework/conf/method/<name>.yaml`` as composed), which :meth:`options_from` turns into one.
    """

    name: ClassVar[str]
    Options: ClassVar[type]
    #: the survey unknowns of scene.yaml this method treats (:func:`refuse_survey_unknowns`):
    #: ``"scale"`` (an emitter's ``scale: unknown``, a sunsky's ``sun_scale``/``sky_scale: unknown``),
    #: ``"known"`` (a segment's ``known`` weights), ``"vignetting"`` (``photometry vignetting``
    #: other than ``none``); the symbolic family treats all three, the baselines none yet
    survey: ClassVar[frozenset[str]] = frozenset()
    #: ``method.tail_bounces``, what ``render.tail_bounces=auto`` resolves to (:mod:`framework.config`):
    #: reflections traced beyond N_max; written into the method's generated YAML
    #: (:mod:`framework.method_yaml`), which a preset overrides (``symbolic_paper``: 0)
    tail_bounces: ClassVar[int] = 4

    def __init__(self, options):
        self.options = options if isinstance(options, self.Options) else self.options_from(options)

    @classmethod
    def options_from(cls, cfg) -> Any:
        """The checked options of the config group ``cfg``: ConfigError (one line naming the key)
        for a missing, unknown or bad option."""
        from framework.config import unknown_method_option
        from framework.options import build
        name = getattr(cls, "name", cls.__name__)
        return cls.check_options(build(cls.Options, cfg, unknown_hint=lambda key: unknown_method_option(key, name)))

    @classmethod
    def check_options(cls, options):
        """What a method refuses beyond each option's own range (a combination, a preset's fixed
        value); returns ``options``."""
        return options

    def parameters(self, problem: Problem) -> list[Parameter]:
        """The unknowns this method estimates (default: all of ``problem.parameters``); the
        weights of kernels it leaves out are 0 in its model."""
        return list(problem.parameters)

    def check_problem(self, problem: Problem) -> None:
        """Raise :class:`ConfigError` (one line) when this method cannot treat ``problem`` (e.g.
        photographs of unknown per-view exposure); called before any run folder is written."""

    @abstractmethod
    def run(self, problem: Problem) -> MethodResult:
        ...

    @abstractmethod
    def render_at(self, problem: Problem, rho: np.ndarray, *, seed: int = 0) -> dict[str, np.ndarray]:
        """The selected views as this method's own forward model renders them at ρ ((P, C), in
        ``problem.parameters`` order; kernels outside :meth:`parameters` count as 0): what its
        cost compares with the observations. One render at ``problem.settings.spp``, seeded by
        ``seed``. Tests use it to check that every method renders the scene it claims."""


def refuse_survey_unknowns(scene, method: type[Method]) -> None:
    """Raise :class:`ConfigError` (one line naming the emitter, segment or key) when ``scene``
    declares an unknown emitter scale, a known segment or a vignetting profile that the method
    class ``method`` does not treat (:attr:`Method.survey`): running it would silently take them
    as absent. Called before the observations are rendered."""
    name = method.name
    where = f"{scene.root}/scene.yaml" if getattr(scene, "root", None) is not None else "scene.yaml"
    if "scale" not in method.survey:
        for e in scene.emitters:
            if e.scale_unknown:
                key = "scale" if e.part is None else f"{e.part}_scale"
                kind = "sunsky" if e.part is not None else e.type
                raise ConfigError(f"{where}: emitter {e.source} ({kind}) {key}: unknown is not supported by "
                                  f"method={name} yet; give {key} as a number")
    if "known" not in method.survey:
        for seg in scene.segments:
            if seg.known:
                raise ConfigError(f"{where}: segment '{seg.name}' known ({', '.join(seg.known)}) is not "
                                  f"supported by method={name} yet; remove known (give the values as the "
                                  "segment's reference to compare the estimates with them)")
    vignetting = scene.photometry.vignetting
    if "vignetting" not in method.survey and vignetting != "none":
        shown = "estimate" if vignetting == "estimate" else "[a1, a2, a3]"
        raise ConfigError(f"{where}: photometry vignetting: {shown} is not supported by method={name} yet; "
                          "correct the photographs for the lens falloff and set vignetting: none")


REGISTRY: dict[str, type[Method]] = {}


def register(name: str):
    """Class decorator: make a :class:`Method` subclass available as ``method=<name>``."""
    def deco(cls: type[Method]) -> type[Method]:
        cls.name = name
        REGISTRY[name] = cls
        return cls
    return deco


def get_method(name: str) -> type[Method]:
    """The registered method ``name``, importing ``methods.<name>`` on first use."""
    if name not in REGISTRY:
        try:
            importlib.import_module(f"methods.{name}")
        except ModuleNotFoundError as exc:
            if exc.name not in (f"methods.{name}", "methods"):
                raise
    if name not in REGISTRY:
        raise ConfigError(f"method={name} is not a registered method; choose one of: "
                          f"{', '.join(available_methods())}")
    return REGISTRY[name]


def available_methods() -> list[str]:
    """Names of the methods that have a config in ``framework/conf/method``."""
    from pathlib import Path
    conf = Path(__file__).parent / "conf" / "method"
    return sorted(p.stem for p in conf.glob("*.yaml"))
