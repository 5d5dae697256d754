#!/usr/bin/env bash
# The test command: bootstrap, then run the whole test suite. Extra arguments go to pytest.
# The suite runs in one worker per core (at most 4; PYTEST_WORKERS=N to choose, 0 for none), each
# test file in one worker; the workers share the session's caches and numba compile locks
# (tests/conftest.py).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
. "$ROOT/scripts/bootstrap.sh"
cd "$ROOT"
workers="${PYTEST_WORKERS:-$(n=$(nproc 2>/dev/null || echo 1); echo $(( n < 4 ? n : 4 )))}"
if [ "$workers" -gt 1 ]; then
  exec "$VENV_PY" -m pytest -q -n "$workers" --dist loadfile "$@"
fi
exec "$VENV_PY" -m pytest -q "$@"
