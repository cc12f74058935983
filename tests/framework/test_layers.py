"""The layering rule of pyproject.toml (import-linter contracts) holds, and it catches a breach."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("framework", "methods", "reports", "scenes", "bench")


def _lint(cwd: Path) -> subprocess.CompletedProcess:
    """``lint-imports`` on the packages found from ``cwd`` (first on the path)."""
    exe = Path(sys.executable).with_name("lint-imports")
    env = {**os.environ, "PYTHONPATH": str(cwd)}
    return subprocess.run([str(exe), "--no-logo", "--no-cache"], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=120)


def _copy_sources(dest: Path) -> None:
    """The Python sources of the packages and pyproject.toml (no data), into ``dest``."""
    for pkg in PACKAGES:
        shutil.copytree(ROOT / pkg, dest / pkg, ignore=lambda d, names: [
            n for n in names if not (n.endswith(".py") or (Path(d) / n).is_dir()) or n == "__pycache__"])
    shutil.copy(ROOT / "pyproject.toml", dest / "pyproject.toml")


def test_layers_kept():
    out = _lint(ROOT)
    assert out.returncode == 0, out.stdout[-2000:]
    assert "0 broken" in out.stdout


def test_upward_import_is_caught(tmp_path):
    """The scene model importing a method breaks the top-level layers (and makes a cycle)."""
    _copy_sources(tmp_path)
    model = tmp_path / "framework" / "scene" / "model.py"
    model.write_text(model.read_text() + "\nimport methods.symbolic  # noqa: E402,F401  (deliberate breach)\n")
    out = _lint(tmp_path)
    assert out.returncode == 1
    assert "framework.scene.model -> methods.symbolic" in out.stdout
    assert "BROKEN" in out.stdout


def test_symbolic_stage_breach_is_caught(tmp_path):
    """The device's trace importing the host's system breaks the symbolic method's stage layers."""
    _copy_sources(tmp_path)
    events = tmp_path / "methods" / "symbolic" / "trace" / "events.py"
    events.write_text(events.read_text() + "\nimport methods.symbolic.system.basis  # noqa: E402,F401  (deliberate breach)\n")
    out = _lint(tmp_path)
    assert out.returncode == 1
    assert "methods.symbolic.trace.events -> methods.symbolic.system.basis" in out.stdout
    assert "Symbolic method" in out.stdout and "BROKEN" in out.stdout
