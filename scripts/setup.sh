#!/usr/bin/env bash
# Idempotent set-up: system libraries, .venv/ at the repository root, the project installed into it.
# Usage: scripts/setup.sh   (called by scripts/run-main.sh and scripts/test.sh; safe to re-run)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"

# --- Debian libraries: libusb for open3d, chromium for the report browser test -----------------
need=()
dpkg -s libusb-1.0-0 >/dev/null 2>&1 || need+=(libusb-1.0-0)
command -v chromium >/dev/null 2>&1 || need+=(chromium)
if [ ${#need[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ]; then sudo=""; elif command -v sudo >/dev/null; then sudo="sudo"; else
    echo "setup: missing Debian packages ${need[*]}: install them as root (apt-get install ${need[*]})" >&2; exit 1; fi
  echo "setup: installing Debian packages: ${need[*]}"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
fi

# --- Python environment --------------------------------------------------------------------------
py="${PYTHON:-python3.11}"
command -v "$py" >/dev/null 2>&1 || py=python3
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv with $($py --version)"
  "$py" -m venv .venv
fi
# Every package at the version requirements.lock pins, hash-checked (scripts/lock.sh refreshes the
# lock); then the project itself, editable, with no dependency resolution and no build isolation,
# so that nothing outside the lock is installed.
stamp=.venv/.installed-$(cat pyproject.toml requirements.lock | sha1sum | cut -c1-12)
if [ ! -f "$stamp" ]; then
  echo "setup: installing requirements.lock into .venv (a few minutes the first time)"
  # pip, setuptools and wheel first (from the lock): the venv's own pip is Python's bundled one,
  # which builds an sdist of the lock (antlr4) the deprecated way without wheel
  bootstrap="$(mktemp)"
  awk '/^(pip|setuptools|wheel)==/{p=1} p{print} p && !/\\$/{p=0}' requirements.lock > "$bootstrap"
  .venv/bin/python -m pip install -q --require-hashes --no-deps -r "$bootstrap"
  rm -f "$bootstrap"
  .venv/bin/python -m pip install -q --require-hashes --no-deps -r requirements.lock
  .venv/bin/python -m pip install -q --no-deps --no-build-isolation -e .
  .venv/bin/python -m pip check
  rm -f .venv/.installed-*; touch "$stamp"
fi

# --- Dr.Jit's libLLVM for every interpreter of the venv ------------------------------------------
# Dr.Jit 1.5 aborts the process with Debian's libLLVM 15; the karellen-llvm-core wheel ships a
# newer one. A .pth file sets DRJIT_LIBLLVM_PATH at interpreter start (also when the venv is not
# activated), and `activate` exports it for the shell, so a user's own script works too.
llvm="$(ls "$root"/.venv/lib/libLLVM.so.* 2>/dev/null | sort -V | tail -n 1)"
if [ -n "$llvm" ]; then
  site="$(.venv/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
  printf "import os; os.environ.setdefault('DRJIT_LIBLLVM_PATH', %s)\n" "'$llvm'" > "$site/_sir_libllvm.pth"
  if ! grep -q "DRJIT_LIBLLVM_PATH" .venv/bin/activate; then
    printf '\n# symbolic-inverse-rendering: a libLLVM >= 16 for Dr.Jit\nexport DRJIT_LIBLLVM_PATH="%s"\n' "$llvm" >> .venv/bin/activate
  fi
fi
