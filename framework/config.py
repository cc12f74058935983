"""The run configuration: Hydra composition, its resolvers, and the typed settings a method gets.

The configuration files live in ``framework/conf`` (``docs/cli.md`` lists every key). Hydra
composes them into a ``DictConfig``; :meth:`RunSettings.from_config` reads the run-wide keys
(``render.*``, ``seed``, ``budget.renders``, ``executor``, ``cache.dir``, ``observe.*``) in
this one place, checks each against its range, and hands methods a frozen, typed object.
Method options (``method.*``) stay with the method, which checks them itself.

Importing this module registers the ``scene_label`` resolver that the run folder names use, so
``compose`` works in tests and the bench without importing the command-line entry.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from hydra import compose as hydra_compose
from hydra import initialize_config_module
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig, OmegaConf

from framework.errors import ConfigError
from framework.executor_options import DaskOptions, SerialOptions, executor_options

#: The bundled scene folders ship beside the framework, in ``scenes/<name>/`` (data only: the
#: framework never imports the ``scenes`` package, whose builders write these folders).
BUNDLED_SCENES = Path(__file__).resolve().parents[1] / "scenes"


def scene_label(name, directory) -> str:
    """Run-folder label of a scene: the bundled name, or the folder's name for ``scene.dir``
    (made absolute first, so that ``scene.dir=.`` is labelled too)."""
    return Path(os.path.abspath(Path(str(directory)).expanduser())).name if directory else str(name)


if not OmegaConf.has_resolver("scene_label"):
    OmegaConf.register_new_resolver("scene_label", scene_label)


def compose(overrides: list[str] | tuple[str, ...] = (), *, hydra_config: bool = False) -> DictConfig:
    """The configuration ``python -m framework.run`` would build from ``overrides`` (inside a
    running Hydra application, from its already initialised config search path); with
    ``hydra_config``, Hydra's own node ``hydra`` too (the run folder ``hydra.run.dir``)."""
    if GlobalHydra.instance().is_initialized():
        return hydra_compose("config", overrides=list(overrides), return_hydra_config=hydra_config)
    with initialize_config_module("framework.conf", version_base=None):
        return hydra_compose("config", overrides=list(overrides), return_hydra_config=hydra_config)


def method_defaults(name: str) -> DictConfig:
    """The shipped options of method ``name`` (``framework/conf/method/<name>.yaml``, defaults
    resolved)."""
    return compose([f"method={name}"]).method


def method_names() -> list[str]:
    """The methods ``method=`` chooses from (``framework/conf/method/<name>.yaml``)."""
    return sorted(p.stem for p in (Path(__file__).parent / "conf" / "method").glob("*.yaml"))


def unknown_method_option(key: str, method: str) -> str:
    """The message for ``key`` (``method.align``), which method ``method`` lacks: the methods
    that have it, or that none has, and ``method``'s own options."""
    parts = key.split(".")[1:]
    having = [n for n in method_names() if n != method and _has_key(method_defaults(n), parts)]
    where = (f"the methods that have it: {', '.join(having)} (choose one with method=<name>)" if having
             else "no method has it")
    own = ", ".join(str(k) for k in method_defaults(method) if k != "name") if method in method_names() else "?"
    return f"{key} is not an option of method {method}: {where}; {method}'s options: {own} (docs/cli.md lists them)"


def _has_key(node, parts: list[str]) -> bool:
    for part in parts:
        if not isinstance(node, DictConfig) or part not in node:
            return False
        node = node[part]
    return True


def scene_dir(cfg: DictConfig) -> Path:
    """``scene.dir`` if given, else the bundled folder of ``scene.name``.

    An empty ``scene.dir=`` is refused (ConfigError) rather than read as null: it would silently
    run the bundled scene instead of the one the user meant to name.
    """
    directory = cfg.scene.get("dir")
    if directory is None:
        return BUNDLED_SCENES / str(cfg.scene.name)
    if not str(directory).strip():
        raise ConfigError("scene.dir is empty: give a scene folder (scene.dir=path/to/scene), "
                          "or scene.dir=null for the bundled scene")
    return Path(str(directory)).expanduser()


#: Largest samples per pixel: Mitsuba's ``sample_count`` is a 32-bit unsigned integer.
SPP_MAX = 2**32 - 1
_SPP_WHY = " (Mitsuba's sample_count is a 32-bit unsigned integer)"


def _integer(key: str, value, lo: int, hi: int | None = None, why: str = "") -> int:
    """``value`` if it is an integer in [lo, hi]; else ConfigError naming ``key``, the range and
    ``why`` (the reason for the range, when it is not obvious)."""
    rng = (f"[{lo}, {hi}]" if hi is not None else f">= {lo}") + why
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{key}={value} is not an integer: use an integer {rng}")
    if value < lo or (hi is not None and value > hi):
        raise ConfigError(f"{key}={value} is out of range: use an integer {rng}")
    return int(value)


def _max_depth(value) -> int:
    """``observe.max_depth``: -1 or >= 2. Mitsuba's max_depth 0 renders nothing and 1 only the
    emitters seen directly, so the observations would not depend on any weight."""
    depth = _integer("observe.max_depth", value, -1)
    if depth in (0, 1):
        raise ConfigError(f"observe.max_depth={depth} renders {'nothing' if depth == 0 else 'only the emitters'}"
                          " (Mitsuba max_depth): use -1 (unbounded) or an integer >= 2")
    return depth


def _noise(value) -> float:
    """``observe.noise``: a finite number >= 0."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"observe.noise={value} is not a number: use a number >= 0")
    if not 0 <= value < float("inf"):
        raise ConfigError(f"observe.noise={value} is out of range: use a finite number >= 0")
    return float(value)


def _variant(value) -> str:
    """``variant``: scalar variants are refused (the methods trace whole images as Dr.Jit arrays)."""
    variant = str(value)
    if variant.startswith("scalar_"):
        raise ConfigError(f"variant={variant} is a scalar variant, and the methods need a JIT one: "
                          "use variant=auto, an llvm_ad_* or (NVIDIA GPU) a cuda_ad_* variant")
    return variant


def requested_views(cfg: DictConfig) -> list[str] | None:
    """The view names ``views`` (or a bundled scene's ``scene.views``) asks for; None for all.

    Raises ConfigError for an empty list or a name listed twice (its residual would count twice).
    """
    views, key = cfg.views, "views"
    if views == "default":
        views, key = (cfg.scene.get("views", "all"), "scene.views") if not cfg.scene.get("dir") else ("all", key)
    if views == "all":
        return None
    names = [str(v) for v in views] if OmegaConf.is_list(views) or isinstance(views, list) else [str(views)]
    if not names:
        raise ConfigError(f"{key}=[] selects no view: name at least one image, or use views=all")
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ConfigError(f"{key} lists {', '.join(twice)} more than once: name each view once")
    return names


@dataclass(frozen=True)
class ObserveSettings:
    """Synthetic observations of scenes without ``images/`` (``observe.*``)."""

    spp: int = 512
    max_depth: int = -1          # Mitsuba max_depth; -1 unbounded, as real light is; never 0 or 1
    noise: float = 0.0           # additive Gaussian noise, std relative to the image mean
    seed: int = 0                # observation stream (odd Mitsuba seeds)

    @classmethod
    def from_config(cls, obs) -> ObserveSettings:
        return cls(spp=_integer("observe.spp", obs.spp, 1, SPP_MAX, _SPP_WHY),
                   max_depth=_max_depth(obs.get("max_depth", -1)),
                   noise=_noise(obs.get("noise", 0.0)), seed=_integer("observe.seed", obs.get("seed", 0), 0))


def _tail_bounces(cfg: DictConfig) -> int:
    """``render.tail_bounces``: an integer in [0, 16], or ``auto`` for the method's own
    ``method.tail_bounces`` (0 when the method has none)."""
    value = cfg.render.get("tail_bounces", "auto")
    if str(value) == "auto":
        method = cfg.get("method") or {}
        return _integer("method.tail_bounces", method.get("tail_bounces", 0), 0, 16)
    return _integer("render.tail_bounces", value, 0, 16)


@dataclass(frozen=True)
class RunSettings:
    """The run-wide settings every method reads, checked once.

    Attributes
    ----------
    spp : int
        ``render.spp``: samples per pixel of the inversion's own renders.
    max_bounces : int
        ``render.max_bounces``: N_max, reflections per path (Mitsuba ``max_depth = N_max + 1``).
    tail_bounces : int
        ``render.tail_bounces``: reflections traced beyond N_max (0 is the paper's truncation);
        ``auto`` (the default) takes the method's ``method.tail_bounces``.
    seed : int
        ``seed``: the run's seed; its renders use even Mitsuba seeds derived from it.
    budget_renders : int
        ``budget.renders``: the most full passes over the views a method may spend.
    variant : str
        The Mitsuba variant in use (``variant=auto``, ``cuda`` or ``llvm`` resolved from the machine and
        the scene's channels once the scene is read; ``auto`` before).
    executor : SerialOptions or DaskOptions
        ``executor.*`` (:mod:`framework.executor_options`).
    cache_dir : str or None
        ``cache.dir``: where observations and polynomial passes are cached (None: no cache).
    observe : ObserveSettings
        ``observe.*``.
    """

    spp: int = 64
    max_bounces: int = 3
    tail_bounces: int = 0
    seed: int = 0
    budget_renders: int = 400
    variant: str = "auto"
    executor: SerialOptions | DaskOptions = field(default_factory=SerialOptions)
    cache_dir: str | None = None
    observe: ObserveSettings = field(default_factory=ObserveSettings)

    @classmethod
    def from_config(cls, cfg: DictConfig, *, variant: str | None = None) -> RunSettings:
        """The checked settings of a composed configuration; ConfigError names the first bad key."""
        return cls(spp=_integer("render.spp", cfg.render.spp, 1, SPP_MAX, _SPP_WHY),
                   max_bounces=_integer("render.max_bounces", cfg.render.max_bounces, 1, 8),
                   tail_bounces=_tail_bounces(cfg),
                   seed=_integer("seed", cfg.seed, 0),
                   budget_renders=_integer("budget.renders", cfg.budget.renders, 1),
                   variant=variant or _variant(cfg.variant),
                   executor=executor_options(cfg.get("executor")),
                   cache_dir=str(cfg.cache.dir) if cfg.cache.get("dir") else None,
                   observe=ObserveSettings.from_config(cfg.observe))
