"""The virtual environment works on its own: a user's script that imports Mitsuba and Dr.Jit
directly (no project module first) must not meet Debian's libLLVM 15, which aborts Dr.Jit 1.5."""
from __future__ import annotations

import os
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
