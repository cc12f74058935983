#!/usr/bin/env bash
# The main job of README.md: set-up (idempotent), then the symbolic inversion of the default
# bundled scene (urban_canyon, one street view), writing results.json and the report.
# Extra arguments are Hydra overrides, e.g. scripts/run-main.sh views=all render.spp=128
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$root/scripts/setup.sh"
cd "$root"
exec .venv/bin/python -m framework.run method=symbolic "$@"
