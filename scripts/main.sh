#!/usr/bin/env bash
# The main job: bootstrap, then simulate a capture session of the default scene and write its outputs
# under runs/default: the live pipeline's map, composites, timing.md and accuracy.json (override with
# OUT=DIR, DURATION=SECONDS; extra arguments go to `simulate`).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
. "$ROOT/scripts/bootstrap.sh"
cd "$ROOT"
exec "$VENV_PY" -m apps.cli simulate --duration "${DURATION:-20}" --out "${OUT:-runs/default}" --overwrite "$@"
