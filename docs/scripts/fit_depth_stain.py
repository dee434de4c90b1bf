"""The depth-resolved fluorescence image (eq. 16) against the 2-D one on ColiCoords cells.

Run: ``python docs/scripts/fit_depth_stain.py [REAL_DATA_DIR]`` (default
``../shared/data/real``). For 64-80 px crops around single cells of ColiCoords ds2 (a
rhodamine-B envelope stain) and ds1 (a cytoplasmic stain, the control): ``fit_scene``
(automatic start, camera estimated, zeros censored; 80 nm pixels, NA 1.4, n 1.515,
0.52 um) with the volume stain and with the envelope's fraction free (from 1), each as
the 2-D model and with 5 slabs through the depth (focal plane free, from 0.2 um). Prints
the table of docs/fitting.md ("the envelope's top and bottom are out of focus") and
writes ``docs/images/fit_depth_ds2.png``: real, 2-D envelope, depth envelope and their
residuals for the ds2 crops.
"""

from __future__ import annotations

import time
from pathlib import Path

import matplotlib
from _args import parse_real_data

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import tifffile

from napari_symbac.fit import fit_scene
from napari_symbac.fit.camera_estimate import censored_pixels
from napari_symbac.settings import Microscope, RenderSettings

ROOT = Path(__file__).resolve().parents[2]
MICROSCOPE = Microscope(
    pixel_size_um=0.08,
    numerical_aperture=1.4,
    refractive_index=1.515,
    wavelength_um=0.52,
    modality="fluorescence",
)
#: (dataset, field, rows, columns) of each crop.
CROPS = (
    ("ds2", "00066", (0, 64), (224, 288)),
    ("ds2", "00074", (290, 354), (388, 452)),
    ("ds2", "00074", (118, 182), (108, 172)),
    ("ds1", "00001", (294, 374), (214, 294)),
)
MODELS = {
    "2-D volume": (RenderSettings(), ("defocus_sigma_um",)),
    "2-D envelope": (
        RenderSettings(envelope_stain_fraction=1.0),
        ("defocus_sigma_um", "envelope_stain_fraction"),
    ),
    "depth volume": (
        RenderSettings(depth_layers=5, focus_offset_um=0.2),
        ("defocus_sigma_um", "focus_offset_um"),
    ),
    "depth envelope": (
        RenderSettings(envelope_stain_fraction=1.0, depth_layers=5, focus_offset_um=0.2),
        ("defocus_sigma_um", "envelope_stain_fraction", "focus_offset_um"),
    ),
}


def main(real_dir: Path) -> None:
    print("| crop | model | reduced chi-square | fraction | width (um) | focal plane (um) | s |")
    print("|---|---|---|---|---|---|---|")
    panels = []
    for dataset, field, rows, cols in CROPS:
        path = real_dir / "colicoords" / "test_data" / dataset / "fluorescence" / f"{field}.tif"
        crop = tifffile.imread(path).astype(float)[slice(*rows), slice(*cols)]
        valid = ~censored_pixels(crop, None)
        fits = {}
        for name, (render, optics) in MODELS.items():
            start = time.perf_counter()
            fit = fit_scene(
                crop, MICROSCOPE, render, None, geometry="open", valid=valid, fit_optics=optics
            )
            seconds = time.perf_counter() - start
            fits[name] = fit
            r = fit.render
            fraction = f"{r.envelope_stain_fraction:.2f}" if "envelope" in name else "-"
            focus = f"{r.focus_offset_um:.2f}" if "depth" in name else "-"
            widths = ", ".join(f"{w:.3f}" for w in fit.cells.width_um)
            print(
                f"| {dataset} {field} {rows} {cols} | {name} | {fit.objective_after:.3f} | "
                f"{fraction} | {widths} | {focus} | {seconds:.1f} |",
                flush=True,
            )
        if dataset == "ds2":
            panels.append((f"{field} {rows} {cols}", crop, valid, fits))
    _figure(panels, ROOT / "docs" / "images" / "fit_depth_ds2.png")


def _figure(panels: list, out: Path) -> None:
    names = ("2-D envelope", "depth envelope")
    fig, axes = plt.subplots(len(panels), 5, figsize=(15, 3.2 * len(panels)))
    for row, (title, crop, valid, fits) in zip(np.atleast_2d(axes), panels):
        top = float(crop.max())
        row[0].imshow(crop, cmap="gray", vmin=0, vmax=top)
        row[0].set_title(f"ds2 {title}")
        for j, name in enumerate(names):
            fit = fits[name]
            row[1 + j].imshow(fit.synthetic, cmap="gray", vmin=0, vmax=top)
            row[1 + j].set_title(f"{name}: chi2 {fit.objective_after:.2f}")
            residual = np.where(valid, fit.residual, 0.0)
            row[3 + j].imshow(residual, cmap="RdBu_r", vmin=-0.15 * top, vmax=0.15 * top)
            row[3 + j].set_title(f"residual, {name}")
        for ax in row:
            ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(out, dpi=70)


if __name__ == "__main__":
    main(parse_real_data(__doc__, "colicoords/test_data"))
