#!/usr/bin/env bash
# The test command: bootstrap, then run the whole test suite. Extra arguments go to pytest.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
. "$ROOT/scripts/bootstrap.sh"
cd "$ROOT"
exec "$VENV_PY" -m pytest -q "$@"
