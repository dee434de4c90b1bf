"""Cell counts of the automatic start and the fit on the 10 ColiCoords ds1 fields.

Run from the repository root::

    python docs/scripts/fit_colicoords_counts.py [REAL_DATA_DIR] [--fit] [--brightfield]

For each 512 x 512 fluorescence field of ``colicoords/test_data/ds1`` (80 nm pixels,
camera estimated, censored zeros; with ``--brightfield`` its bright-field image, NA 1.4
and 0.55 um, clipped pixels censored, and the fit's median width and lens term too):
the published mask's connected components, the
automatic start's cells (on a mask component, off it, and how many of the off-mask
ones touch the image edge, which the mask leaves out), and with ``--fit`` the same
for the fitted cells of ``fit_scene`` with its moves, and the seconds it took. Writes
``docs/images/fit_colicoords_starts.png`` (``..._brightfield.png``): every field
(square-root grey; bright field: its contrast, the start's segmentation) with the
mask outlines (green) and the start's cells (red centres). The real images are read
from ``../shared/data/real`` and never copied.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from _args import add_real_data, checked_real_data, script_parser

ROOT = Path(__file__).resolve().parents[2]
PX = 0.08


def _tally(x_um: np.ndarray, y_um: np.ndarray, labels: np.ndarray, edge_um: float = 1.0):
    rows = np.clip((y_um / PX).astype(int), 0, labels.shape[0] - 1)
    cols = np.clip((x_um / PX).astype(int), 0, labels.shape[1] - 1)
    hit = labels[rows, cols]
    off = hit == 0
    h_um, w_um = labels.shape[0] * PX, labels.shape[1] * PX
    near_edge = (x_um < edge_um) | (y_um < edge_um) | (x_um > w_um - edge_um)
    near_edge |= y_um > h_um - edge_um
    return len(set(hit[hit > 0].tolist())), int(off.sum()), int((off & near_edge).sum())


def main(real: Path, do_fit: bool, brightfield: bool = False) -> None:
    import tifffile
    from scipy import ndimage

    from napari_symbac.fit import fit_scene
    from napari_symbac.fit.camera_estimate import censored_pixels
    from napari_symbac.fit.start import start_scene
    from napari_symbac.settings import Microscope, RenderSettings

    folder = real / "colicoords" / "test_data" / "ds1"
    if brightfield:
        microscope = Microscope(
            pixel_size_um=PX, numerical_aperture=1.4, wavelength_um=0.55, modality="brightfield"
        )
    else:
        microscope = Microscope(pixel_size_um=PX, modality="fluorescence")
    channel = "brightfield" if brightfield else "fluorescence"
    tiles = []
    print(
        "| field | mask | start: cells: on mask / off (at edge) "
        "| fit: cells: on mask / off (at edge) | s |"
    )
    for index in range(1, 11):
        image = tifffile.imread(folder / channel / f"{index:05d}.tif").astype(float)
        mask = tifffile.imread(folder / "binary" / f"{index:05d}_Probabilities_filtered.tif")
        labels, count = ndimage.label(mask > 0)
        valid = ~censored_pixels(image)
        cells = start_scene(image, microscope, geometry="open", valid=valid)[0]
        on, off, edge = _tally(cells.x_um, cells.y_um, labels)
        line = f"| {index} | {count} | {len(cells)}: {on} / {off} ({edge}) |"
        if do_fit:
            t0 = time.perf_counter()
            fit = fit_scene(image, microscope, RenderSettings(), None, geometry="open")
            seconds = time.perf_counter() - t0
            f_on, f_off, f_edge = _tally(fit.cells.x_um, fit.cells.y_um, labels)
            line += f" {len(fit.cells)}: {f_on} / {f_off} ({f_edge}) | {seconds:.0f} |"
            if brightfield:
                width = float(np.median(fit.cells.width_um))
                line += f" {width:.3f} | {fit.render.defocus_contrast_um2:+.4f} |"
        print(line, flush=True)
        from skimage.segmentation import find_boundaries

        if brightfield:  # dark cells shown bright
            shown = -ndimage.gaussian_filter(image, 1.0)
            shown = np.clip(shown - np.percentile(shown, 1), 0, None)
            grey = np.sqrt(shown / np.percentile(shown, 99.9))
        else:
            grey = np.sqrt(np.clip(image, 0, None) / np.percentile(image, 99.9))
        rgb = np.repeat(np.clip(grey, 0, 1)[..., None], 3, axis=-1)
        rgb[find_boundaries(labels)] = (0, 1, 0)
        for x, y in zip(cells.x_um, cells.y_um):
            r, c = int(y / PX), int(x / PX)
            rgb[max(r - 3, 0) : r + 4, max(c - 3, 0) : c + 4] = (1, 0, 0)
        tiles.append((rgb[::2, ::2] * 255).astype(np.uint8))
    gap = np.zeros((256, 4, 3), np.uint8)
    rows = []
    for k in (0, 5):
        row = [tiles[k]]
        for tile in tiles[k + 1 : k + 5]:
            row += [gap, tile]
        rows.append(np.concatenate(row, 1))
    from PIL import Image

    figure = np.concatenate([rows[0], np.zeros((4, rows[0].shape[1], 3), np.uint8), rows[1]], 0)
    # a 256-colour palette halves the file (the grey noise compresses poorly)
    name = "fit_colicoords_starts_brightfield" if brightfield else "fit_colicoords_starts"
    Image.fromarray(figure).quantize(colors=256).save(
        ROOT / "docs" / "images" / f"{name}.png", optimize=True
    )


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line: ``[REAL_DATA_DIR] [--fit] [--brightfield]``."""
    parser = script_parser(__doc__)
    add_real_data(parser)
    parser.add_argument(
        "--fit", action="store_true", help="fit every field as well (fit_scene; minutes)"
    )
    parser.add_argument(
        "--brightfield", action="store_true", help="the bright-field images, not fluorescence"
    )
    args = parser.parse_args(argv)
    checked_real_data(parser, args.real, "colicoords/test_data/ds1")
    return args


if __name__ == "__main__":
    args = parse_args()
    main(args.real, args.fit, args.brightfield)
