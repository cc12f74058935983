#!/usr/bin/env bash
# Refreshes requirements.lock: every package of the venv (the project's dependencies, the test
# extra and the build tools of scripts/lock.in) at an exact version with its hashes, resolved by
# uv for CPython 3.11 on Linux x86-64. Run it after changing a dependency in pyproject.toml, then
# commit requirements.lock; scripts/setup.sh installs exactly what it lists.
# Usage: scripts/lock.sh [--upgrade]   (--upgrade: newest versions the pins allow)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
tool="$(mktemp -d)"
trap 'rm -rf "$tool"' EXIT
python3 -m venv "$tool"
"$tool/bin/python" -m pip install -q "uv==0.13.9"
"$tool/bin/uv" pip compile pyproject.toml scripts/lock.in --extra test --python-version 3.11 \
  --generate-hashes --custom-compile-command "scripts/lock.sh" -o requirements.lock "$@"
