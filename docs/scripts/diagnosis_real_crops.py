"""Crops of the ColiCoords fluorescence fields of docs/diagnosis.md (MIT data, Smit et al. 2019).

Run: ``python docs/scripts/diagnosis_real_crops.py REAL_DATA_DIR OUT_DIR``. Writes
``ds1_flu_crop.tif`` (one background-subtracted field, 128 x 128) and
``ds3_flu_crop.tif`` (the first frame of ds3/flu.tif, camera offset kept, 128 x 128: its
4 frames are 4 different fields, not a time series, so each frame is a recording of its
own; the window of frame 0 holds no cell in frame 1), each the 128 x 128 window with the
most mask pixels, and ``fluorescence.json`` (assumed
microscope: ColiCoords records no optics; 80 nm pixels, NA 1.4 oil, 0.52 um).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import tifffile
from _args import add_real_data, checked_real_data, script_parser
from scipy import ndimage

SIZE = 128


def best_window(mask: np.ndarray) -> tuple[int, int]:
    counts = ndimage.uniform_filter((mask > 0).astype(float), SIZE, mode="constant")
    half = SIZE // 2
    inner = counts[half : mask.shape[0] - half, half : mask.shape[1] - half]
    r, c = np.unravel_index(np.argmax(inner), inner.shape)
    return int(r), int(c)


def main(real: Path, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    cc = real / "colicoords" / "test_data"
    flu = tifffile.imread(cc / "ds1" / "fluorescence" / "00001.tif")
    mask = tifffile.imread(cc / "ds1" / "binary" / "00001_Probabilities_filtered.tif")
    r, c = best_window(mask)
    tifffile.imwrite(out / "ds1_flu_crop.tif", flu[r : r + SIZE, c : c + SIZE])
    series = tifffile.imread(cc / "ds3" / "flu.tif")
    masks = tifffile.imread(cc / "ds3" / "binary.tif")
    r, c = best_window(masks[0])
    tifffile.imwrite(out / "ds3_flu_crop.tif", series[0, r : r + SIZE, c : c + SIZE])
    microscope = {
        "modality": "fluorescence",
        "pixel_size_um": 0.08,
        "NA": 1.4,
        "refractive_index": 1.515,
        "wavelength_um": 0.52,
    }
    (out / "fluorescence.json").write_text(json.dumps(microscope, indent=2))


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line: ``REAL_DATA_DIR OUT_DIR``."""
    parser = script_parser(__doc__)
    add_real_data(parser, required=True)
    parser.add_argument("out", type=Path, metavar="OUT_DIR", help="where the crops go")
    args = parser.parse_args(argv)
    checked_real_data(parser, args.real, "colicoords/test_data")
    return args


if __name__ == "__main__":
    args = parse_args()
    main(args.real, args.out)
