#!/usr/bin/env bash
# Install the test extras into ./.venv (reused on a second run) and run the whole test
# suite headless: ruff, then pytest with pytest-qt; napari's canvas runs under Xvfb,
# which pytest-xvfb starts. Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}
QT_SYSTEM_LIBS="xvfb libgl1 libegl1 libxkbcommon-x11-0 libxcb-cursor0 libxcb-icccm4 \
libxcb-keysyms1 libxcb-image0 libxcb-render-util0 libxcb-shape0 libxcb-randr0 \
libxcb-xinerama0 libfontconfig1 libdbus-1-3"

missing=""
if command -v dpkg >/dev/null 2>&1; then
  for pkg in $QT_SYSTEM_LIBS; do
    dpkg -s "$pkg" >/dev/null 2>&1 || missing="$missing $pkg"
  done
fi
if [ -n "$missing" ]; then
  if [ "$(id -u)" = 0 ]; then SUDO=""; elif sudo -n true 2>/dev/null; then SUDO="sudo -n"; else SUDO="none"; fi
  if [ "$SUDO" = none ]; then
    echo "run-tests: missing system packages for headless Qt/OpenGL:$missing" >&2
    echo "run-tests: install them with: sudo apt-get install -y --no-install-recommends$missing" >&2
    exit 1
  fi
  echo "run-tests: installing$missing" >&2
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends $missing >/dev/null
fi

[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
# torch runs the batched render path and the transfer benchmark's U-Net on the CPU in the
# tests. 2.13.0 is a CPU build on the CI machines' disk; elsewhere set TORCH_SPEC (e.g. to
# "torch --index-url https://download.pytorch.org/whl/cpu") to avoid a multi-GB CUDA build.
.venv/bin/python -c "import torch" 2>/dev/null || .venv/bin/python -m pip install -q ${TORCH_SPEC:-torch==2.13.0}
.venv/bin/python -m pip install -q -e ".[test]"

.venv/bin/ruff check src tests benchmarks tools
# Qt's offscreen platform draws the vispy canvas through the X display of the Xvfb
# server that pytest-xvfb starts; --xvfb-backend makes a missing Xvfb an error instead
# of a silent run without OpenGL (vispy's GL_EXTENSIONS query then returns None).
export QT_QPA_PLATFORM=offscreen
exec .venv/bin/python -m pytest --xvfb-backend xvfb "$@"
