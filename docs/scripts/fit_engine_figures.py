"""Figures and numbers of the scene-fit engine for docs/fitting.md (issue 10).

Run from the repository root::

    python docs/scripts/fit_engine_figures.py [REAL_DATA_DIR]

Fits the real 100x trench (GPL-2 SyMBac sample data) and a 120 x 250 crop of the
ColiCoords ds1 fluorescence field 1 (MIT), both with the camera estimated from the
data, prints the counts, sizes and timings, and writes

* ``docs/images/fit_engine_trench.png``: real with the fitted outlines | start |
  fitted | residual;
* ``docs/images/fit_engine_colicoords.png``: the crop with the published mask's
  outlines (green) and the fitted cells' (red) | residual.

The real images are read from ``../shared/data/real`` and never copied.
"""

from __future__ import annotations

import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import tifffile
from _args import parse_real_data
from scipy import ndimage

from napari_symbac.fit import fit_scene
from napari_symbac.fit.scene_fit import before_after_montage
from napari_symbac.fit.start import cells_from_instances
from napari_symbac.settings import Microscope, RenderSettings

ROOT = Path(__file__).resolve().parents[2]
IMAGES = ROOT / "docs" / "images"


def _outline(labels: np.ndarray) -> np.ndarray:
    from skimage.segmentation import find_boundaries

    return find_boundaries(labels, mode="inner") & (labels > 0)


def _grey(image: np.ndarray) -> np.ndarray:
    low, high = np.percentile(image, [0.5, 99.5])
    grey = np.clip((image - low) / max(high - low, 1e-9), 0, 1)
    return np.repeat((grey * 255).astype(np.uint8)[..., None], 3, axis=-1)


def _residual_rgb(res: np.ndarray) -> np.ndarray:
    limit = max(float(np.percentile(np.abs(res), 99)), 1e-9)
    v = np.clip(res / limit, -1, 1)
    rgb = np.stack(
        [255 * (1 - np.maximum(-v, 0)), 255 * (1 - np.abs(v)), 255 * (1 - np.maximum(v, 0))], -1
    )
    return rgb.astype(np.uint8)


def _report(fit, seconds: float) -> None:
    print(f"cells {len(fit.cells)} (start {len(fit.initial_cells)}), {seconds:.1f} s")
    print(f"moves: {'; '.join(fit.moves) or 'none'}")
    print(f"reduced chi-square {fit.objective_before:.3f} -> {fit.objective_after:.3f}")
    cam = fit.camera
    print(f"camera: gain {cam.sensitivity_adu_per_e:.2f} ADU/e-, read {cam.dark_noise_e:.2f} e-")
    rms = float(np.sqrt(np.mean(fit.residual[fit.valid] ** 2)))
    print(f"residual rms {rms:.1f} ADU; warnings: {'; '.join(fit.warnings) or 'none'}")


def trench(real: Path) -> None:
    image = tifffile.imread(real / "ecoli_100x_oil_exponential.tiff")
    start = time.perf_counter()
    fit = fit_scene(
        image, Microscope(pixel_size_um=0.065), RenderSettings(), None, closed_end="round"
    )
    print("## Real 100x trench (256 x 46, 0.065 um/px)")
    _report(fit, time.perf_counter() - start)
    table = fit.cells_table()
    for i in range(len(fit.cells)):
        print(
            f"cell {i + 1}: y {table['y_um'][i]:.2f} um, length {table['length_um'][i]:.2f} "
            f"+- {table['length_um_se'][i]:.3f} um, width {table['width_um'][i]:.3f} "
            f"+- {table['width_um_se'][i]:.3f} um"
        )
    overlay = _grey(image)
    overlay[_outline(fit.scene.camera_labels())] = (255, 0, 0)
    gap = np.zeros((image.shape[0], 3, 3), np.uint8)
    figure = np.concatenate([overlay, gap, before_after_montage(image, fit)], axis=1)
    iio.imwrite(IMAGES / "fit_engine_trench.png", np.repeat(np.repeat(figure, 2, 0), 2, 1))


def colicoords(real: Path) -> None:
    folder = real / "colicoords" / "test_data" / "ds1"
    crop = (slice(80, 200), slice(60, 310))
    image = tifffile.imread(folder / "fluorescence" / "00001.tif")[crop]
    mask = tifffile.imread(folder / "binary" / "00001_Probabilities_filtered.tif")[crop]
    labels, count = ndimage.label(mask > 0)
    microscope = Microscope(pixel_size_um=0.08, modality="fluorescence")
    start = time.perf_counter()
    fit = fit_scene(image, microscope, RenderSettings(), None, geometry="open")
    print(f"\n## ColiCoords ds1 field 1, crop 120 x 250 (0.08 um/px); mask components: {count}")
    _report(fit, time.perf_counter() - start)
    masked, mask_width = cells_from_instances(labels, 0.08, max_cell_length_um=np.inf)
    table = fit.cells_table()
    print(
        "\n| cell | fitted length | mask length | Otsu length | fitted width | mask width "
        "| Otsu width | intensity |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for i in range(len(fit.cells)):
        j = int(
            np.argmin(np.hypot(masked.x_um - fit.cells.x_um[i], masked.y_um - fit.cells.y_um[i]))
        )
        print(
            f"| {i + 1} | {table['length_um'][i]:.2f} +- {table['length_um_se'][i]:.2f} "
            f"| {masked.length_um[j]:.2f} | {table['otsu_length_um'][i]:.2f} "
            f"| {table['width_um'][i]:.2f} +- {table['width_um_se'][i]:.2f} | {mask_width[j]:.2f} "
            f"| {table['otsu_width_um'][i]:.2f} | {table['intensity_adu'][i]:.0f} |"
        )
    overlay = _grey(image)
    overlay[_outline(labels)] = (0, 255, 0)
    overlay[_outline(fit.scene.camera_labels())] = (255, 0, 0)
    gap = np.zeros((image.shape[0], 3, 3), np.uint8)
    figure = np.concatenate([overlay, gap, _residual_rgb(fit.residual)], axis=1)
    iio.imwrite(IMAGES / "fit_engine_colicoords.png", np.repeat(np.repeat(figure, 2, 0), 2, 1))


def main(real: Path) -> None:
    trench(real)
    colicoords(real)


if __name__ == "__main__":
    main(parse_real_data(__doc__, "ecoli_100x_oil_exponential.tiff and colicoords/test_data"))
