#!/usr/bin/env bash
# Make a virtual environment with SyMBac 0.5.2 for the side-by-side benchmarks
# (`napari-symbac bench --symbac-python DIR/bin/python`). SyMBac is never a dependency of
# napari-symbac: it runs in this separate interpreter, in a subprocess.
#
#   bash tools/make-symbac-env.sh [DIR]      # default DIR: ./symbac-venv
#
# Headless: SyMBac imports pyglet-based drawing only when a window is shown; the benchmarks
# call run_simulation(show_window=False), and opencv comes as its headless wheel.
set -euo pipefail
DIR="${1:-symbac-venv}"
PYTHON="${PYTHON:-python3}"
"$PYTHON" -m venv "$DIR"
"$DIR/bin/python" -m pip install --quiet --upgrade pip
"$DIR/bin/python" -m pip install --quiet "SyMBac==0.5.2"
# SyMBac 0.5.2 pulls opencv-python (needs libGL); the headless build has the same API.
if "$DIR/bin/python" -m pip show opencv-python >/dev/null 2>&1; then
    "$DIR/bin/python" -m pip uninstall --quiet --yes opencv-python
    "$DIR/bin/python" -m pip install --quiet opencv-python-headless
fi
"$DIR/bin/python" - <<'PY'
import SyMBac.simulation, SyMBac.renderer, SyMBac.PSF  # noqa: F401
from importlib.metadata import version
print("SyMBac", version("SyMBac"), "imports")
PY
echo "SyMBac interpreter: $DIR/bin/python"
