"""Reading and checking run folders for the reports (docs/results.md)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

from framework.errors import UserError

RESULTS_NAME = "results.json"
REQUIRED_KEYS = ("method", "scene", "channels", "parameters")
KERNEL_SYMBOLS = {"diffuse": ("ρ_d", "ρ<sub>d</sub>"), "specular": ("ρ_s", "ρ<sub>s</sub>")}


class ReportError(UserError):
    """A run or sweep folder the report cannot read; the message names the path and the fix."""


def load_results(run_dir: str | os.PathLike) -> dict:
    """Load and check ``<run_dir>/results.json``.

    Parameters
    ----------
    run_dir : str or path-like
        A run folder.

    Returns
    -------
    dict
        The parsed results.

    Raises
    ------
    ReportError
        If the file is missing, is not JSON, or lacks a required key.
    """
    path = Path(run_dir) / RESULTS_NAME
    if not path.is_file():
        raise ReportError(f"{path}: not found; pass a run folder that holds {RESULTS_NAME} "
                          "(a finished run) or a sweep folder containing such runs")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ReportError(f"{path}: unreadable JSON ({exc}); re-run the method to rewrite it "
                          "or remove the broken run folder") from exc
    return check_results(path, data)


def check_results(path: Path, data) -> dict:
    """``data`` if it has the shape of docs/results.md the report needs; ReportError naming
    ``path`` otherwise."""
    if not isinstance(data, dict):
        raise ReportError(f"{path}: expected a JSON object, got {type(data).__name__}; "
                          "re-run the method to rewrite it")
    missing = [k for k in REQUIRED_KEYS if k not in data]
    if missing:
        raise ReportError(f"{path}: missing key(s) {', '.join(missing)}; results.json must "
                          "follow docs/results.md (re-run the method to rewrite it)")
    if not isinstance(data["parameters"], list) or not isinstance(data["channels"], list):
        raise ReportError(f"{path}: 'parameters' and 'channels' must be lists (docs/results.md)")
    for i, par in enumerate(data["parameters"]):
        if not isinstance(par, dict) or "segment" not in par or "kernel" not in par:
            raise ReportError(f"{path}: parameters[{i}] needs 'segment' and 'kernel' "
                              "(docs/results.md)")
    for field, value, (shape, ok) in _typed_fields(data):
        if not ok(value):
            text = repr(value)
            raise ReportError(f"{path}: {field} must be {shape}, got {text[:60] + '...' if len(text) > 63 else text}; "
                              "re-run the method to rewrite it (docs/results.md)")
    return data


def _number(x) -> bool:
    """A finite number: results.json writes NaN and infinities as null (docs/results.md)."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _numbers(x) -> bool:
    """A list of numbers, null where unknown."""
    return isinstance(x, list) and all(v is None or _number(v) for v in x)


def _matrix(rows: int, cols: int):
    """``(words, check)`` of a ``rows`` x ``cols`` list of lists of numbers."""
    return (f"{rows} lists (one per parameter) of {cols} numbers",
            lambda x: isinstance(x, list) and len(x) == rows and all(_numbers(r) and len(r) == cols for r in x))


#: What the fields of results.json that the reports compute with may hold, as ``(words of the
#: error message, check)``. The reports turn them into arrays and figures: checking them all
#: first is what lets a bad file fail before any report file is written.
NUMBER = ("a number", _number)
NUMBER_OR_NULL = ("a number or null", lambda x: x is None or _number(x))


def _per_channel(channels: list) -> tuple[str, object]:
    """``(words, check)`` of a per-channel field: a list of one finite number (or null) per
    channel, a single number (the same in every channel), or null."""
    names = ", ".join(map(str, channels))
    return (f"{len(channels)} finite numbers (one per channel: {names}; null where unknown) or null",
            lambda x: x is None or _number(x) or (_numbers(x) and len(x) == len(channels)))


NUMBER_LIST = ("a list of numbers", _numbers)
OBJECT_LIST = ("a list of objects", lambda x: isinstance(x, list) and all(isinstance(v, dict) for v in x))
TOP_LEVEL = {
    "renders": NUMBER_OR_NULL, "image_rmse": NUMBER_OR_NULL,
    "cost_history": NUMBER_LIST, "cost_times_s": NUMBER_LIST,
    "timings_s": ("an object of numbers",
                  lambda x: isinstance(x, dict) and all(v is None or _number(v) for v in x.values())),
    "solve_stages_s": ("an object of numbers",
                       lambda x: isinstance(x, dict) and all(v is None or _number(v) for v in x.values())),
    "settings": ("an object", lambda x: isinstance(x, dict)),
    "correlation": ("an object", lambda x: isinstance(x, dict)),
    "segments": ("a list", lambda x: isinstance(x, list)),
    "views": OBJECT_LIST, "relit": OBJECT_LIST, "trace": OBJECT_LIST, "exposure": OBJECT_LIST,
    "illumination": OBJECT_LIST, "vignetting": OBJECT_LIST,
}


def _typed_fields(data: dict):
    """``(field, value, (words, check))`` of every present, non-null field the reports compute with."""
    yield from ((k, data[k], shape) for k, shape in TOP_LEVEL.items() if data.get(k) is not None)
    for i, par in enumerate(data["parameters"]):
        yield from ((f"parameters[{i}].{k}", par[k], _per_channel(data["channels"]))
                    for k in ("estimate", "reference", "error", "std") if k in par)
    correlation = data.get("correlation")
    if isinstance(correlation, dict) and "matrix" in correlation:
        n = len(correlation["matrix"]) if isinstance(correlation["matrix"], list) else 0
        yield "correlation.matrix", correlation["matrix"], (f"a {n} x {n} list of numbers", _matrix(n, n)[1])
    estimate = _matrix(len(data["parameters"]), len(data["channels"]))
    for i, entry in enumerate(data.get("trace") or []):
        if isinstance(entry, dict):
            yield f"trace[{i}].estimate", entry.get("estimate"), estimate
            yield from ((f"trace[{i}].{k}", entry.get(k), NUMBER) for k in ("time_s", "renders"))


def find_run_dirs(dirs) -> list[Path]:
    """Run folders named by ``dirs``: each is a run folder or searched recursively.

    Parameters
    ----------
    dirs : sequence of str or path-like
        Run folders or sweep folders.

    Returns
    -------
    list of pathlib.Path
        Sorted, without duplicates.

    Raises
    ------
    ReportError
        If a path does not exist or holds no ``results.json``.
    """
    if not dirs:
        raise ReportError("no folder given; pass run folders or sweep folders containing "
                          f"{RESULTS_NAME}")
    found: set[Path] = set()
    for d in map(Path, dirs):
        if not d.is_dir():
            raise ReportError(f"{d}: no such folder; pass an existing run or sweep folder")
        hits = [d] if (d / RESULTS_NAME).is_file() else [p.parent for p in d.rglob(RESULTS_NAME)]
        if not hits:
            raise ReportError(f"{d}: no {RESULTS_NAME} found in it or below; pass a finished "
                              "run folder or a sweep folder containing finished runs")
        found.update(h.resolve() for h in hits)
    return sorted(found)


def as_list(value, n: int) -> list:
    """A per-channel list of length ``n`` from a number, a list or None."""
    if value is None:
        return [None] * n
    if isinstance(value, (int, float)):
        return [float(value)] * n
    vals = list(value)
    return vals if len(vals) == n else (vals + [None] * n)[:n]


def fmt_num(value, *, digits: int = 4) -> str:
    """Format a number for a table: fixed decimals, scientific when tiny, '—' when missing."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "—"
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return str(value)
    if math.isinf(value):
        return "∞" if value > 0 else "-∞"
    if value != 0 and abs(value) < 0.5 * 10.0 ** -digits:
        return f"{value:.2e}"
    return f"{value:.{digits}f}"


def fmt_pm(mean, std, *, digits: int = 4) -> str:
    """Format ``mean ± std`` (std omitted when None)."""
    if std is None or (isinstance(std, float) and math.isnan(std)):
        return fmt_num(mean, digits=digits)
    return f"{fmt_num(mean, digits=digits)} ± {fmt_num(std, digits=digits)}"


def kernel_label(kernel: str, *, html: bool = False) -> str:
    """The paper's symbol for a kernel (ρ_d, ρ_s; ρ_g(α) for ``glossy(α)``), or the kernel's name."""
    pair = KERNEL_SYMBOLS.get(kernel)
    if pair is None and kernel.startswith("glossy(") and kernel.endswith(")"):
        alpha = kernel[len("glossy("):-1]
        pair = (f"ρ_g(α={alpha})", f"ρ<sub>g</sub>(α={alpha})")
    if pair is None:
        return kernel
    return pair[1] if html else pair[0]


def device_of(results: dict) -> str:
    """Where a run rendered, in words: ``<variant> on <device>`` from its ``settings`` (the variant
    alone for a run that did not record its device)."""
    settings = results.get("settings") or {}
    variant, device = settings.get("variant") or "unknown variant", settings.get("device")
    return f"{variant} on {device}" if device else f"{variant} (device not recorded)"


def seed_of(results: dict):
    """The run's seed from ``settings.seed`` (or a top-level ``seed``), else None."""
    settings = results.get("settings") or {}
    return settings.get("seed", results.get("seed")) if isinstance(settings, dict) else None
