"""Command line: ``python -m framework.run method=symbolic scene=urban_canyon`` (Hydra).

A thin entry: the work is :func:`framework.experiment.run_experiment`, the run report
:func:`reports.write_run_report`. A user error prints one line (``error: ...``) and exits with
status 2, leaving no results.json; Ctrl-C prints ``interrupted`` and exits with 130. Every
override is listed in ``docs/cli.md``.

Hydra creates the run folder and writes ``.hydra/`` and ``<job>.log`` into it before ``main``
runs, so a check made in ``main`` comes too late to keep a folder untouched. :func:`preflight`
therefore reads the command line first: the override syntax, the config-group choices, the
composed configuration (:func:`framework.experiment.check_config`) and the run folder
(:meth:`framework.results.RunFolder.claim`); it then pins ``hydra.run.dir`` to the folder it
checked, since ``${now:...}`` could name another one a second later. A failed run removes what
it wrote and nothing else.
"""
from __future__ import annotations

import dataclasses
import logging
import re
import signal
import sys
from pathlib import Path

import hydra
from hydra._internal.utils import get_args_parser
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import HydraException, OverrideParseException
from omegaconf import DictConfig
from omegaconf.errors import OmegaConfBaseException

from framework.cache import Cache
from framework.config import RunSettings, compose, scene_dir, unknown_method_option
from framework.errors import ConfigError, UserError
from framework.experiment import check_config, run_experiment
from framework.results import HYDRA_NAMES, RunFolder
from reports import write_run_report

log = logging.getLogger("framework.run")

CONF_DIR = Path(__file__).parent / "conf"
#: The config groups a user chooses on the command line, and what one choice is called.
GROUPS = {"method": "a method", "scene": "a bundled scene", "executor": "an executor"}
#: Hydra's flags (argparse names) with which nothing runs: left to Hydra as they are.
INSPECT_FLAGS = ("help", "hydra_help", "cfg", "info", "shell_completion", "experimental_rerun")
#: Flags that compose another configuration than ``framework/conf/config.yaml``.
OTHER_CONFIG_FLAGS = ("config_name", "config_path", "config_dir")

_claimed: RunFolder | None = None      # the run folder preflight checked, before Hydra started
_interrupted = False                   # set on Ctrl-C, whatever exception a library turns it into
_created_cache: Path | None = None     # the topmost cache folder this run created (removed on failure)


def _missing_top(path: Path | None) -> Path | None:
    """The topmost missing folder of ``path`` (what creating it would create), None if it exists."""
    if path is None:
        return None
    path, top = Path(path).expanduser().absolute(), None
    while not path.exists() and path != path.parent:
        path, top = path.parent, path
    return top


def _check_cache(cache_dir) -> None:
    """:meth:`Cache.check_writable`, remembering the folder it creates, if any."""
    global _created_cache
    top = _missing_top(Cache(cache_dir).dir)
    Cache(cache_dir).check_writable()
    if top is not None and _created_cache is None:
        _created_cache = top


def _discard_cache() -> None:
    """After a failed run: remove the cache folder it created, if nothing but empty folders is
    in it (a cache entry written meanwhile, by this run or another, stays)."""
    global _created_cache
    top, _created_cache = _created_cache, None
    if top is None or not top.is_dir():
        return
    for folder in sorted((p for p in top.rglob("*") if p.is_dir()), key=lambda p: len(p.parts), reverse=True):
        try:
            folder.rmdir()
        except OSError:
            pass
    try:
        top.rmdir()
    except OSError:
        pass


def _on_sigint(signum, frame) -> None:
    """Python's own Ctrl-C behaviour, remembered: Dr.Jit re-raises a KeyboardInterrupt raised
    inside a rendering as a RuntimeError, which must not read as a failure of the run."""
    global _interrupted
    _interrupted = True
    raise KeyboardInterrupt


def _override_error(text: str, exc: OverrideParseException) -> str:
    """One line for an override Hydra's grammar cannot read."""
    key, _, value = text.partition("=")
    if not text.isascii() and value[:1] not in ("'", '"'):
        return (f"{text}: Hydra reads non-ASCII characters only inside quotes; "
                f"write the argument as '{key}=\"{value}\"'")
    lines = str(exc).splitlines()
    detail = lines[1] if lines[0].startswith("Error parsing") and len(lines) > 1 else lines[0]
    return (f"cannot read the override {text!r} ({detail}): write key=value, and quote values "
            "with spaces or special characters (docs/cli.md)")


def parse_overrides(texts) -> list:
    """Hydra's parsed overrides of ``texts``; ConfigError naming the one it cannot read."""
    parser = OverridesParser.create()
    parsed = []
    for text in texts:
        try:
            parsed += parser.parse_overrides([text])
        except OverrideParseException as exc:
            raise ConfigError(_override_error(text, exc)) from None
    return parsed


def check_choices(overrides) -> None:
    """Each ``method=``, ``scene=`` and ``executor=`` choice (also each value of a sweep) names a
    file of ``framework/conf/<group>/``; ConfigError listing the choices otherwise (Hydra's own
    message spans a dozen lines)."""
    for o in overrides:
        if o.key_or_group not in GROUPS or o.package is not None or o.value() is None or (
                o.is_sweep_override() and not o.is_choice_sweep()):
            continue
        values = list(o.sweep_string_iterator()) if o.is_sweep_override() else [o.get_value_element_as_str()]
        choices = sorted(p.stem for p in (CONF_DIR / o.key_or_group).glob("*.yaml"))
        for value in values:
            if value not in choices:
                extra = ", or scene.dir=path/to/scene for any scene folder" if o.key_or_group == "scene" else ""
                raise ConfigError(f"{o.key_or_group}={value} is not {GROUPS[o.key_or_group]}; "
                                  f"choose one of: {', '.join(choices)}{extra}")


def _first_lines(exc: Exception) -> str:
    """Hydra's or OmegaConf's message up to its first blank line, as one line, without the
    indented context lines (``full_key: ...``) and links."""
    lines = []
    for line in str(exc).splitlines():
        if not line.strip():
            break
        if not line[0].isspace() and not line.startswith("See https"):
            lines.append(line)
    return " ".join(lines)


def _checked_config(overrides) -> tuple[DictConfig, RunSettings]:
    """The configuration Hydra will compose (its own ``hydra`` node included), and its checked
    settings."""
    try:
        cfg = compose(overrides, hydra_config=True)
        return cfg, check_config(cfg)
    except (HydraException, OmegaConfBaseException) as exc:
        _refuse_method_option(exc, overrides)
        key = getattr(exc, "full_key", None)        # OmegaConf's: the key whose value failed
        raise ConfigError(f"{key + ': ' if key else ''}{_first_lines(exc)} (docs/cli.md lists the keys)") from None


def _refuse_method_option(exc: Exception, overrides) -> None:
    """Raise ConfigError naming the methods that have the option when ``exc`` is Hydra's refusal of
    an override of a ``method.*`` key the chosen method lacks (its own hint, ``+key=value``, only
    moves the refusal to the method's option check)."""
    found = re.match(r"Could not override '(method\.[^']+)'", str(exc))
    if found:
        chosen = [o for o in overrides if not o.startswith(("method.", "+method.", "~method."))]
        method = str(compose(chosen).method.name)
        raise ConfigError(unknown_method_option(found.group(1), method)) from None


def _quoted(path: Path) -> str:
    """``path`` as a quoted value of Hydra's override grammar (spaces, commas, ``=`` survive).

    In that grammar a backslash escapes only a quote or the backslashes before one, so those
    (and the ones before the closing quote) are doubled; ``${`` is escaped against interpolation.
    """
    text = re.sub(r"(\\*)'", lambda m: m.group(1) * 2 + "\\'", str(path))
    text = re.sub(r"(\\+)$", lambda m: m.group(1) * 2, text).replace("${", "\\${")
    return f"'{text}'"


def preflight(argv: list[str]) -> list[str]:
    """Check the command line before Hydra runs; return the arguments to hand to Hydra.

    A plain run gets its configuration checked and its run folder claimed here, and
    ``hydra.run.dir`` pinned to that folder. Sweep jobs are checked as they start (:func:`main`).
    ConfigError on bad input, before anything is written.
    """
    global _claimed
    args = get_args_parser().parse_args(argv)
    if any(getattr(args, flag) for flag in INSPECT_FLAGS):
        return argv
    check_choices(parse_overrides(args.overrides))
    if args.multirun or any(getattr(args, flag) for flag in OTHER_CONFIG_FLAGS):
        return argv
    cfg, settings = _checked_config(args.overrides)
    try:
        run_dir = Path(str(cfg.hydra.run.dir)).expanduser()
    except OmegaConfBaseException:         # ${hydra:...} resolves only in Hydra: claimed in main
        return argv
    _claimed = RunFolder.claim(run_dir, scene_root=scene_dir(cfg))
    _check_cache(settings.cache_dir)             # after the claim: it may create a folder in it
    return [a for a in argv if not a.startswith("hydra.run.dir=")] + [f"hydra.run.dir={_quoted(_claimed.path)}"]


def _run_folder(cfg: DictConfig, run_dir: Path) -> RunFolder:
    """The folder preflight claimed, or (a sweep job, or a run folder only Hydra can name) the
    folder claimed now, Hydra having written ``.hydra/`` and the log into it already."""
    log_name = f"{HydraConfig.get().job.name}.log"
    if _claimed is not None and _claimed.path == run_dir:
        return dataclasses.replace(_claimed, log_name=log_name)
    key = "hydra.run.dir" if HydraConfig.get().mode.name == "RUN" else "hydra.sweep.dir/subdir"
    return RunFolder.claim(run_dir, scene_root=scene_dir(cfg), key=key,
                           hydra_written=(*HYDRA_NAMES, log_name), log_name=log_name)


@hydra.main(version_base=None, config_path="conf", config_name="config")
def main(cfg: DictConfig) -> None:
    global _created_cache
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    folder = None
    try:
        folder = _run_folder(cfg, run_dir)
        if _created_cache is None:           # a sweep job, or a run folder only Hydra names
            _check_cache(check_config(cfg).cache_dir)
        run_experiment(cfg, run_dir, write_report=write_run_report if cfg.get("report", True) else None)
        _created_cache = None                # a finished run's cache stays
    except UserError as exc:
        if _interrupted:                     # Ctrl-C that a library reported as an error
            if folder is not None:
                folder.discard()
            _discard_cache()
            raise KeyboardInterrupt from None
        print(f"error: {exc}", file=sys.stderr)
        log.error("%s", exc)
        if folder is not None:
            folder.discard()                 # no partial output; nothing that was there before
        _discard_cache()
        if HydraConfig.get().mode.name == "RUN":
            sys.exit(2)                      # in a sweep, the next job still runs
    except BaseException as exc:
        if not (_interrupted or isinstance(exc, KeyboardInterrupt)):
            raise                            # a bug: a traceback, the folder kept to look into
        if folder is not None:
            folder.discard()
        _discard_cache()
        raise KeyboardInterrupt from None


def cli(argv: list[str] | None = None) -> None:
    """``python -m framework.run``: :func:`preflight`, then Hydra and :func:`main`."""
    signal.signal(signal.SIGINT, _on_sigint)
    try:
        sys.argv[1:] = preflight(sys.argv[1:] if argv is None else argv)
        main()
    except UserError as exc:
        if not _interrupted:
            _discard_cache()
            print(f"error: {exc}", file=sys.stderr)
            sys.exit(2)
        _interrupted_exit()
    except KeyboardInterrupt:
        _interrupted_exit()


def _interrupted_exit() -> None:
    """Ctrl-C (also one a library reported as an error): ``interrupted``, status 130, what the
    run wrote removed."""
    _discard_cache()
    if _claimed is not None:
        _claimed.discard()                   # interrupted before main: what Hydra wrote
    print("interrupted", file=sys.stderr)
    sys.exit(130)


if __name__ == "__main__":
    cli()
