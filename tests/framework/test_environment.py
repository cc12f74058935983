"""The virtual environment works on its own: a user's script that imports Mitsuba and Dr.Jit
directly (no project module first) must not meet Debian's libLLVM 15, which aborts Dr.Jit 1.5."""
from __future__ import annotations

import os

import pytest
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
USER_SCRIPT = ("import mitsuba as mi; mi.set_variant('llvm_ad_rgb'); import drjit as dr; "
               "print(dr.minimum(mi.Float([1, 3]), mi.Float(2)))")


def test_plain_interpreter_of_the_venv_runs_dr_jit(tmp_path):
    """Not activated, no DRJIT_LIBLLVM_PATH, outside the repository: the venv's .pth sets it."""
    env = {k: v for k, v in os.environ.items() if k not in ("DRJIT_LIBLLVM_PATH", "PYTHONPATH")}
    out = subprocess.run([sys.executable, "-c", USER_SCRIPT], cwd=tmp_path, env=env, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-500:]
    assert out.stdout.strip() == "[1, 2]"


def test_activate_exports_libllvm():
    """``source .venv/bin/activate`` exports a DRJIT_LIBLLVM_PATH that exists, LLVM >= 16."""
    out = subprocess.run(["bash", "-c", f"source {ROOT / '.venv/bin/activate'} && echo $DRJIT_LIBLLVM_PATH"],
                         env={k: v for k, v in os.environ.items() if k != "DRJIT_LIBLLVM_PATH"},
                         capture_output=True, text=True, timeout=30)
    path = out.stdout.strip()
    assert path and Path(path).is_file()
    from framework.render.backend import MIN_LLVM_MAJOR, llvm_major
    assert llvm_major(path) >= MIN_LLVM_MAJOR


def test_auto_variant_prefers_cuda_when_usable(monkeypatch):
    """``variant=auto`` is CUDA when Dr.Jit's CUDA backend starts, else LLVM, by the scene's channels."""
    from framework.render import backend
    monkeypatch.setattr(backend, "cuda_usable", lambda: True)
    assert backend.auto_variant(("R", "G", "B")) == "cuda_ad_rgb"
    assert backend.auto_variant(("Y",)) == "cuda_ad_mono"
    assert backend.jit_backend("auto") == "cuda"
    monkeypatch.setattr(backend, "cuda_usable", lambda: False)
    assert backend.auto_variant(("R", "G", "B")) == "llvm_ad_rgb"
    assert backend.auto_variant(("Y",)) == "llvm_ad_mono"
    assert backend.jit_backend("cuda_ad_mono") == "cuda"


def test_backend_names_pick_the_colour_mode():
    """``variant=llvm`` is the LLVM variant of the scene's colour mode."""
    from framework.render import backend
    assert backend.set_variant("llvm", channels=("Y",)) == "llvm_ad_mono"
    assert backend.set_variant("llvm", channels=("R", "G", "B")) == "llvm_ad_rgb"


def test_auto_variant_that_cannot_start_says_what_it_tried(monkeypatch):
    """When auto picks CUDA and CUDA does not start, the message names the variant auto chose."""
    from framework.errors import ConfigError
    from framework.render import backend
    if backend.cuda_usable():
        pytest.skip("CUDA starts on this machine")
    monkeypatch.setattr(backend, "cuda_usable", lambda: True)
    with pytest.raises(ConfigError, match=r"variant=auto chose cuda_ad_rgb, which cannot start .* llvm_ad_\*"):
        backend.set_variant("auto", channels=("R", "G", "B"))


def test_no_code_path_names_an_llvm_variant():
    """Every variant is chosen through :mod:`framework.render.backend` (auto, the run's backend):
    a literal ``llvm_ad_*`` in code would keep a GPU machine without libLLVM from running it."""
    import re
    from pathlib import Path
    root = Path(__file__).resolve().parents[2]
    found = []
    for folder in ("framework", "methods", "reports", "bench", "scenes"):
        for path in (root / folder).rglob("*.py"):
            for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                code = line.split("#", 1)[0]
                if re.search(r"""set_variant\(\s*["']llvm""", code):
                    found.append(f"{path.relative_to(root)}:{n}")
    assert not found, found


def test_device_is_named():
    """results.json's ``device``: the CPU model and cores for an LLVM variant."""
    import os
    from framework.render import backend
    assert backend.device_name("llvm_ad_rgb").endswith(f", {len(os.sched_getaffinity(0))} cores")
