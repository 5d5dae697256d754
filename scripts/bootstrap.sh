#!/usr/bin/env bash
# Set up everything a fresh machine lacks, idempotently: Debian packages the stack needs, a virtualenv
# in .venv, then the project and its dependencies (with the dev extra: torch 2.13.0 (CPU) first).
# Quick when already done: a stamp keyed by the hash of this file and pyproject.toml skips pip.
# Source it (". scripts/bootstrap.sh") or run it; it leaves VENV_PY pointing at the venv's python.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
LOG="$ROOT/.venv-bootstrap.log"

# libusb: open3d imports only with it; EGL/GL: pyrender's offscreen context (Mesa); libgomp: numba/open3d;
# libcgal-demo: ships the Stanford bunny (data/meshes/bunny00.off), the default virtual object;
# libllvm19: Mitsuba's vectorised llvm_ad_rgb variant (drjit loads libLLVM-19.so), used for the lit
# world's bake and reference frames.
apt_packages=(libusb-1.0-0 libegl1 libgl1 libgomp1 libcgal-demo libllvm19)
missing=()
for p in "${apt_packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "bootstrap: installing Debian packages: ${missing[*]}" >&2
  SUDO=""
  [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq >>"$LOG" 2>&1
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >>"$LOG" 2>&1 || {
    echo "bootstrap: apt-get install failed; see $LOG" >&2; exit 1; }
fi

# BOOTSTRAP_EXTRAS: the project's extras to install (comma-separated), "dev" (tests, rerun-sdk, and
# torch + kornia as test references) unless the caller says otherwise; the main job asks for none
# (rerun-sdk and pyarrow are 650 MB, 6 s of a first run; torch 700 MB; none is imported at run time).
# A venv set up with "dev" serves both.
extras="${BOOTSTRAP_EXTRAS-dev}"
stamp_hash="$(cat "$ROOT/scripts/bootstrap.sh" "$ROOT/pyproject.toml" | sha256sum | cut -c1-16)"
stamp="$VENV/.bootstrap-$stamp_hash-${extras:-base}"
if [ ! -f "$stamp" ] && [ ! -f "$VENV/.bootstrap-$stamp_hash-dev" ]; then
  echo "bootstrap: setting up $VENV (a few minutes the first time; log in $LOG)" >&2
  [ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
  # --no-compile: no byte-compiling of every installed module up front (torch alone: 66 → 35 s);
  # Python compiles what is imported, once, on first use.
  {
    # Chained with &&: set -e does not apply inside a list followed by ||, so a failed torch install
    # would otherwise go on to the project's, and kornia would pull in the CUDA build.
    "$VENV/bin/python" -m pip install -q --no-compile --upgrade pip &&
    # The dev extra's kornia needs torch: the CPU build first, pinned; an unpinned torch pulled in by
    # kornia would be a multi-GB CUDA build. Without the dev extra nothing needs torch.
    case ",$extras," in
      *,dev,*) "$VENV/bin/python" -m pip install -q --no-compile torch==2.13.0 ;;
    esac &&
    "$VENV/bin/python" -m pip install -q --no-compile -e "$ROOT${extras:+[$extras]}"
  } >>"$LOG" 2>&1 || { echo "bootstrap: pip failed; see $LOG" >&2; tail -20 "$LOG" >&2; exit 1; }
  find "$VENV" -maxdepth 1 -name '.bootstrap-*' ! -name ".bootstrap-$stamp_hash-*" -delete  # other versions' stamps
  touch "$stamp"
fi
export VENV_PY="$VENV/bin/python"
