"""Mitsuba / Dr.Jit start-up: a usable libLLVM and a validated variant.

Dr.Jit 1.5's LLVM backend aborts the whole process with libLLVM 15 (Debian's default), so the
library is located and checked *before* Dr.Jit is imported, and a missing one is a
:class:`~framework.errors.EnvironmentSetupError` with the fix, never an abort.
"""
from __future__ import annotations

import glob
import os
import platform
import re
import sys

from framework.errors import ConfigError, EnvironmentSetupError

MIN_LLVM_MAJOR = 16
_SYSTEM_GLOBS = ("/usr/lib/x86_64-linux-gnu/libLLVM*.so*", "/usr/lib/llvm-*/lib/libLLVM*.so*",
                 "/usr/lib64/libLLVM*.so*", "/usr/local/lib/libLLVM*.so*")
_FIX = ("install a libLLVM >= 16: run scripts/setup.sh (pip wheel karellen-llvm-core), "
        "or 'apt-get install libllvm19', or set DRJIT_LIBLLVM_PATH to such a libLLVM.so")


def llvm_major(path: str) -> int | None:
    """Major LLVM version encoded in a library file name (``libLLVM-19.so``, ``libLLVM.so.23.1``)."""
    m = re.search(r"libLLVM[-.](?:so\.)?(\d+)", os.path.basename(os.path.realpath(path)))
    return int(m.group(1)) if m else None


def find_libllvm() -> str | None:
    """Newest libLLVM >= 16: the virtual environment's (karellen-llvm-core) first, then the system's."""
    venv = sorted(glob.glob(os.path.join(sys.prefix, "lib", "libLLVM*.so*")))
    candidates = venv + sorted(p for g in _SYSTEM_GLOBS for p in glob.glob(g))
    usable = [p for p in candidates if (llvm_major(p) or 0) >= MIN_LLVM_MAJOR]
    return max(usable, key=llvm_major) if usable else None


def ensure_libllvm() -> str:
    """Point Dr.Jit at a usable libLLVM (``DRJIT_LIBLLVM_PATH``) or raise with the fix."""
    given = os.environ.get("DRJIT_LIBLLVM_PATH")
    if given:
        if not os.path.isfile(given):
            raise EnvironmentSetupError(f"DRJIT_LIBLLVM_PATH={given} does not exist: {_FIX}")
        major = llvm_major(given)
        if major is not None and major < MIN_LLVM_MAJOR:
            raise EnvironmentSetupError(
                f"DRJIT_LIBLLVM_PATH={given} is LLVM {major}, Dr.Jit 1.5 aborts with it: {_FIX}")
        return given
    found = find_libllvm()
    if found is None:
        raise EnvironmentSetupError(f"no libLLVM >= {MIN_LLVM_MAJOR} found: {_FIX}")
    os.environ["DRJIT_LIBLLVM_PATH"] = found
    return found


def point_at_libllvm() -> None:
    """Set ``DRJIT_LIBLLVM_PATH`` to a usable libLLVM if one is found and none is set; never raises
    (:func:`set_variant` raises with the fix when an LLVM variant is asked for without one)."""
    if not os.environ.get("DRJIT_LIBLLVM_PATH"):
        found = find_libllvm()
        if found is not None:
            os.environ["DRJIT_LIBLLVM_PATH"] = found


def cuda_usable() -> bool:
    """Whether Dr.Jit can start its CUDA backend here (an NVIDIA driver and GPU)."""
    import drjit as dr
    try:
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:       # a driver that fails to initialise counts as no GPU
        return False


def auto_variant(channels: tuple[str, ...] | None) -> str:
    """What ``variant=auto`` means here: ``cuda_ad_rgb`` / ``cuda_ad_mono`` (from ``channels``)
    when CUDA is usable, else ``llvm_ad_rgb`` / ``llvm_ad_mono``."""
    colour = "mono" if channels == ("Y",) else "rgb"
    return f"{'cuda' if cuda_usable() else 'llvm'}_ad_{colour}"


def jit_backend(variant: str | None = None) -> str:
    """``cuda`` or ``llvm``: the backend of ``variant`` (default: the active Mitsuba variant; with
    none active or a scalar one, the backend ``variant=auto`` would pick). Side evaluations (the
    sunsky bake) run there, so a run on a GPU never needs a libLLVM."""
    if variant is None:
        import mitsuba as mi
        variant = mi.variant() or ""
    if variant.startswith(("cuda", "llvm")):
        return variant[:4]
    return "cuda" if cuda_usable() else "llvm"


def use_backend(variant: str) -> None:
    """Make ``variant``'s backend (``auto`` resolved) the active one before the scene is read, so
    that what the loader evaluates with Mitsuba (the sunsky) runs on the run's device; the run's
    variant proper is set by :func:`set_variant` once the scene's channels are known."""
    set_variant(f"{jit_backend(variant)}_ad_rgb")


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), or the platform's processor string."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def set_variant(variant: str, *, channels: tuple[str, ...] | None = None) -> str:
    """Select a Mitsuba variant; ``auto`` is :func:`auto_variant` (CUDA when usable, else LLVM);
    ``cuda`` or ``llvm`` name a backend, whose ``*_ad_rgb`` or ``*_ad_mono`` variant ``channels`` picks.

    Raises :class:`ConfigError` for an unknown variant or one whose colour mode does not match
    the scene's channels (an ``rgb`` scene needs an ``*_rgb`` variant, a ``mono`` scene ``*_mono``).
    """
    asked = variant
    if variant == "auto":
        variant = auto_variant(channels)
    elif variant in ("cuda", "llvm"):           # a backend: the JIT variant of the scene's colour mode
        variant = f"{variant}_ad_{'mono' if channels == ('Y',) else 'rgb'}"
    if variant.startswith("llvm") or variant.startswith("scalar"):
        ensure_libllvm()
    import mitsuba as mi
    if variant not in mi.variants():
        raise ConfigError(f"variant={variant} is not a Mitsuba variant of this build; "
                          f"choose one of: {', '.join(mi.variants())}")
    if channels is not None:
        mono = variant.endswith("_mono")
        if mono != (channels == ("Y",)) or not (mono or variant.endswith("_rgb")):
            want = "*_mono" if channels == ("Y",) else "*_rgb"
            raise ConfigError(f"variant={variant} does not match the scene's channels "
                              f"{''.join(channels)}: use a {want} variant (or variant=auto)")
    try:
        mi.set_variant(variant)
    except Exception as exc:  # e.g. cuda_* without a GPU
        how = f"variant=auto chose {variant}" if asked == "auto" else f"variant={variant}"
        other = "llvm_ad_*" if variant.startswith("cuda") else "cuda_ad_* (NVIDIA GPU)"
        raise ConfigError(f"{how}, which cannot start on this machine ({exc}); "
                          f"use a {other} variant") from None
    return variant


def device_name(variant: str | None = None) -> str:
    """The device a Mitsuba ``variant`` (default: the active one, :func:`jit_backend`) renders on,
    in words: the GPU's name for a ``cuda_*`` variant (CUDA device 0, the one Dr.Jit uses), else
    the CPU's model and the cores this process may use."""
    if jit_backend(variant) == "cuda":
        return _cuda_device_name() or "unknown CUDA GPU"
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return f"{cpu_model()}, {cores} cores"


def _cuda_device_name() -> str | None:
    """Name of CUDA device 0 from the driver library (the one Dr.Jit loads), or None."""
    import ctypes
    try:
        cuda = ctypes.CDLL("libcuda.so.1")
        device, name = ctypes.c_int(), ctypes.create_string_buffer(256)
        if cuda.cuInit(0) or cuda.cuDeviceGet(ctypes.byref(device), 0) \
                or cuda.cuDeviceGetName(name, len(name), device):
            return None                 # a CUresult other than CUDA_SUCCESS (0)
        return name.value.decode(errors="replace")
    except (OSError, AttributeError):
        return None
