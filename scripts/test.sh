#!/usr/bin/env bash
# The test command of README.md: set-up (idempotent), the layering rule (import-linter), then the
# whole test suite.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$root/scripts/setup.sh"
cd "$root"
export SIR_CACHE_DIR="${SIR_CACHE_DIR:-$root/.cache/test}"
.venv/bin/lint-imports --no-logo --no-cache
exec .venv/bin/python -m pytest "$@"
