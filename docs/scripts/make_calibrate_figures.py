"""Figures of docs/proof.md: ``napari-symbac calibrate`` on a ColiCoords field (in
fluorescence and in bright field) and an Omnipose colony (real data of
``../shared/data/real``, MIT), report.png copied to docs/images and report.txt printed.

Run: ``python docs/scripts/make_calibrate_figures.py``.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

import imageio.v3 as iio
import tifffile
from _args import REAL_DATA, checked_real_data, script_parser

from napari_symbac.cli import main

ROOT = Path(__file__).resolve().parents[2]
REAL = REAL_DATA
IMAGES = ROOT / "docs" / "images"


def run(name: str, image, masks, microscope: str, extra: list[str]) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        tifffile.imwrite(tmp / "image.tif", image)
        tifffile.imwrite(tmp / "masks.tif", masks)
        (tmp / "microscope.yaml").write_text(microscope)
        code = main(
            ["calibrate", str(tmp / "image.tif"), "--masks", str(tmp / "masks.tif"),
             "--microscope", str(tmp / "microscope.yaml"), "--out", str(tmp / "out"),
             "--n-items", "4", "--formats", "tiff", *extra]
        )
        if code:
            sys.exit(code)
        shutil.copy(tmp / "out" / "report.png", IMAGES / f"calibrate_{name}.png")
        print(f"===== {name}\n" + (tmp / "out" / "report.txt").read_text())


def main_figures() -> None:
    ds1 = REAL / "colicoords" / "test_data" / "ds1"
    run(
        "colicoords",
        tifffile.imread(ds1 / "fluorescence" / "00001.tif"),
        tifffile.imread(ds1 / "binary" / "00001_Probabilities_filtered.tif"),
        "pixel_size_um: 0.08\nwavelength_um: 0.53\nmodality: fluorescence\n",
        [],
    )
    run(
        "colicoords_brightfield",
        tifffile.imread(ds1 / "brightfield" / "00001.tif"),
        tifffile.imread(ds1 / "binary" / "00001_Probabilities_filtered.tif"),
        "pixel_size_um: 0.08\nwavelength_um: 0.55\nnumerical_aperture: 1.4\n"
        "modality: brightfield\n",
        [],
    )
    folder = REAL / "omnipose"
    image = iio.imread(folder / "Sample000033.png")[..., 0]
    masks = tifffile.imread(folder / "Sample000033_cp_masks.tif")
    run(
        "omnipose",
        image,
        masks,
        "wavelength_um: 0.55\nmodality: phase\n",
        ["--cell-width-um", "1.0"],
    )


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line: no arguments (``--help`` prints the docstring above); the real
    recordings are read from ../shared/data/real beside the repository."""
    parser = script_parser(__doc__)
    args = parser.parse_args(argv)
    checked_real_data(parser, REAL, "colicoords/test_data and omnipose", given="repository")
    return args


if __name__ == "__main__":
    parse_args()
    main_figures()
