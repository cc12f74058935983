"""Description of the machine and software the benchmark ran on."""
from __future__ import annotations

import datetime
import os
import platform
import subprocess

from bench.common import ROOT
from framework.render import backend


def _mem_gib() -> float:
    try:
        for line in open("/proc/meminfo", encoding="utf-8"):
            if line.startswith("MemTotal"):
                return int(line.split()[1]) / 2**20
    except OSError:
        pass
    return float("nan")


#: files ``python -m bench`` writes itself
OWN_OUTPUTS = ("bench/results", "BENCHMARKS.md", "README.md")


def _git() -> str:
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                             text=True).stdout.strip()
        # the bench's own outputs (stored sections, BENCHMARKS.md, README's table) are not code: a
        # bench run that measures one section after another changes them between sections
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", ".",
                                *(f":(exclude){p}" for p in OWN_OUTPUTS)], cwd=ROOT,
                               capture_output=True, text=True).stdout.strip()
        return rev + (" (with uncommitted changes)" if dirty else "")
    except OSError:
        return "unknown"


def describe(variant: str = "auto") -> dict:
    """CPU model, cores, RAM, the Mitsuba variant (``auto``, a backend ``cuda``/``llvm`` or a variant)
    and its device, versions, Python, date, git revision."""
    variant = backend.set_variant(variant, channels=("R", "G", "B"))
    import drjit as dr
    import mitsuba as mi
    return {"cpu": backend.cpu_model(), "cores": os.cpu_count(), "ram_gib": _mem_gib(),
            "variant": f"{variant} (rgb scenes), {variant.replace('_rgb', '_mono')} (mono scenes)",
            "device": backend.device_name(variant), "mitsuba": mi.__version__,
            "drjit": dr.__version__, "python": platform.python_version(), "platform": platform.platform(),
            "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"), "git": _git()}
