#!/usr/bin/env bash
# Diagnosis of the real recordings shown in docs/diagnosis.md.
# Usage: docs/scripts/diagnosis_real.sh REAL_DATA_DIR OUT_DIR   (REAL_DATA_DIR = ../shared/data/real)
set -euo pipefail
real=$1
out=$2
mkdir -p "$out"
cat > "$out/phase100x.json" <<JSON
{"modality": "phase", "pixel_size_um": 0.065, "NA": 1.45, "refractive_index": 1.518,
 "wavelength_um": 0.65, "condenser": "Ph3", "objective": "100x oil"}
JSON
napari-symbac diagnose "$real/ecoli_100x_oil_exponential.tiff" --microscope "$out/phase100x.json" \
  --out "$out/ecoli_100x"
python "$(dirname "$0")/diagnosis_real_crops.py" "$real" "$out/colicoords"
napari-symbac diagnose "$out/colicoords/ds1_flu_crop.tif" --microscope "$out/colicoords/fluorescence.json" \
  --out "$out/colicoords_ds1"
napari-symbac diagnose "$out/colicoords/ds3_flu_crop.tif" --microscope "$out/colicoords/fluorescence.json" \
  --out "$out/colicoords_ds3"
