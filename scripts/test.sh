#!/usr/bin/env bash
# The test command of README.md: set-up (idempotent), then the whole test suite.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$root/scripts/setup.sh"
cd "$root"
export SIR_CACHE_DIR="${SIR_CACHE_DIR:-$root/.cache/test}"
exec .venv/bin/python -m pytest "$@"
