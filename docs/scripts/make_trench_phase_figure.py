"""Figure and numbers of docs/rendering.md, "The SyMBac trench with the partially coherent model".

On the real 100x trench ``ecoli_100x_oil_exponential.tiff`` (GPL-2 SyMBac sample data,
read from ``../shared/data/real``, never copied), the scene of ``fit_scene`` (closed end
round, linear model) is rendered with ``phase_model="partially_coherent"`` and fitted
(pixel term) three ways:

* ``transparent``: cells and PDMS pure phase objects (bright-field transmission 1, as
  a cell and clear PDMS are); fitted cell and PDMS phase, apodisation, ring width,
  defocus;
* ``kept``: the bright-field transmissions kept from the linear fit (its intensities
  over the media's), the same five parameters: the fit of issue 16;
* ``pdms``: as ``transparent`` plus the PDMS' transmission free
  (``device_transmission``; freeing the cells' as well runs it to 1, its upper bound).

Writes ``docs/images/trench_phase_profiles.png`` (real | fitted | residual, and the mean
intensity against the signed distance to the cells' outline and to the trench walls)
and ``docs/images/trench_phase_numbers.json``. Run from the repository root:
``python docs/scripts/make_trench_phase_figure.py`` (~5 minutes on 2 shared cores).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import matplotlib
from _args import checked_real_data, real_data_from_environment, script_parser

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import tifffile

from napari_symbac.fit import fit_parameters, fit_scene, scene_classes
from napari_symbac.fit.masks import distance_profile
from napari_symbac.settings import Microscope, RenderSettings

sys.path.insert(0, str(Path(__file__).resolve().parent))
from make_phase_figures import save  # 256-colour PNG

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "images"
REAL = real_data_from_environment()
MICROSCOPE = Microscope(pixel_size_um=0.065)  # 100x oil, NA 1.45, 0.65 um, Ph3
FIVE = (
    "cell_phase_rad",
    "device_phase_rad",
    "apodisation_sigma_um",
    "phase_ring_width_scale",
    "defocus_sigma_um",
)
FITS = {
    "transparent": (FIVE, 1.0, 1.0),
    "kept": (FIVE, None, None),
    "pdms": ((*FIVE, "device_transmission"), 1.0, 0.9),
}
#: Start of the optics (the phase of a ~1 um cell / of a ~1.2 um deep trench in PDMS).
START = {
    "phase_model": "partially_coherent",
    "cell_phase_rad": 0.9,
    "device_phase_rad": 1.0,
    "apodisation_sigma_um": 1.5,
    "phase_ring_width_scale": 1.5,
    "defocus_sigma_um": 0.05,
    "plate_transmission": 0.25,
    "source_points": 24,
}
EDGES_PX = np.arange(-8.0, 14.0)


def main() -> None:
    image = tifffile.imread(REAL / "ecoli_100x_oil_exponential.tiff")
    scene_fit = fit_scene(image, MICROSCOPE, RenderSettings(), None, closed_end="round")
    scene, linear, camera = scene_fit.scene, scene_fit.render, scene_fit.camera
    cells = scene.camera_labels() > 0
    trench = scene_classes(scene) != 3
    numbers = {
        "linear": {
            "reduced_chi2": scene_fit.objective_after,
            "rms_adu": float(np.sqrt(np.mean(scene_fit.residual**2))),
        }
    }
    synthetic = {"linear": image - scene_fit.residual}
    for name, (names, b_cell, b_device) in FITS.items():
        start = dict(START)
        if b_cell is not None:
            start["cell_intensity"] = b_cell * linear.media_intensity
            start["device_intensity"] = b_device * linear.media_intensity
        render = dataclasses.replace(linear, **start)
        clock = time.perf_counter()
        fit = fit_parameters(
            image, None, scene, MICROSCOPE, render, camera, terms=("pixel",), fit=names,
            max_evaluations=160, global_search=False,
        )
        r = fit.render
        numbers[name] = {
            "reduced_chi2": fit.objective_after,
            "rms_adu": float(np.sqrt(np.mean(fit.residual**2))),
            "seconds": round(time.perf_counter() - clock),
            "renders": fit.n_evaluations,
            "media_intensity": r.media_intensity,
            "cell_transmission": r.cell_intensity / r.media_intensity,
            "device_transmission": r.device_intensity / r.media_intensity,
            **{n: float(getattr(r, n)) for n in FIVE},
            "warnings": list(fit.warnings),
        }
        synthetic[name] = image - fit.residual
        print(name, json.dumps(numbers[name], indent=1), flush=True)
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "trench_phase_numbers.json").write_text(json.dumps(numbers, indent=1))

    low, high = np.percentile(image, [0.5, 99.5])
    residual = image - synthetic["transparent"]
    limit = float(np.percentile(np.abs(residual), 99.5))
    fig = plt.figure(figsize=(11, 6.4))
    grid = fig.add_gridspec(2, 5, width_ratios=(1, 1, 1, 4.5, 4.5))
    for i, (img, cmap, (vmin, vmax), title) in enumerate(
        (
            (image, "gray", (low, high), "real"),
            (synthetic["transparent"], "gray", (low, high), "fitted"),
            (residual, "RdBu_r", (-limit, limit), "residual"),
        )
    ):
        a = fig.add_subplot(grid[:, i])
        a.imshow(img, cmap=cmap, vmin=vmin, vmax=vmax)
        a.set_title(title, fontsize=9)
        a.set_xticks([])
        a.set_yticks([])
    x_um = (EDGES_PX[:-1] + 0.5) * MICROSCOPE.pixel_size_um
    styles = {
        "real": ("k-", "real"),
        "transparent": ("C3-", "partially coherent, transparent (B = 1)"),
        "pdms": ("C2-.", "partially coherent, PDMS transmission fitted"),
        "kept": ("C1:", "partially coherent, B of the linear fit"),
        "linear": ("C0--", "linear (weak-phase) fit"),
    }
    for row, (mask, what) in enumerate(((cells, "cells' outline"), (trench, "trench walls"))):
        a = fig.add_subplot(grid[row, 3:])
        for key, (style, label) in styles.items():
            img = image if key == "real" else synthetic[key]
            chi2 = "" if key == "real" else f" (chi2 {numbers[key]['reduced_chi2']:.1f})"
            a.plot(x_um, distance_profile(img.astype(float), mask, EDGES_PX), style,
                   label=label + chi2)
        a.axvline(0, color="0.7", lw=0.8)
        a.set_xlabel(f"signed distance to the {what} (um), negative inside")
        a.set_ylabel("mean intensity (ADU)")
        if row == 0:
            a.legend(fontsize=7)
    fig.tight_layout()
    save(fig, OUT / "trench_phase_profiles.png")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line: no arguments (``--help`` prints the docstring above); the real
    recordings are read from $NAPARI_SYMBAC_REAL_DATA, else ../shared/data/real."""
    parser = script_parser(__doc__)
    args = parser.parse_args(argv)
    checked_real_data(parser, REAL, "ecoli_100x_oil_exponential.tiff", given="environment")
    return args


if __name__ == "__main__":
    parse_args()
    main()
