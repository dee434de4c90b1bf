"""Issue 16's table for calibrated synthetic colonies: normalised class medians, real vs synthetic.

Run: ``python docs/scripts/phase_class_medians.py REAL_DATA_DIR [N_SYNTHETIC]``. For each
Omnipose colony (MIT, ``REAL_DATA_DIR/omnipose``): ``calibrate`` with its masks exactly as
``benchmarks/bench_transfer.py`` does (pixel size from the masks and a 1 um width, 0.55 um
light, a 160 px crop, 25 renders), then ``N_SYNTHETIC`` images of the matched dataset, each
compared with the real image by ``calibrate.compare_images`` (1-99 percentile normalisation;
cells = mask > 0, background = more than 6 px from every cell). Prints one row per image.
"""

from __future__ import annotations

import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import tifffile

from napari_symbac.calibrate import calibrate, compare_images, export_settings
from napari_symbac.export.dataset import PipelineSource
from napari_symbac.settings import Microscope


def main() -> None:
    folder = Path(sys.argv[1]) / "omnipose"
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 2
    print("| image | real cells | real background | synthetic cells | synthetic background |")
    print("|---|---|---|---|---|")
    for path in sorted(folder.glob("Sample*.png")):
        data = np.asarray(iio.imread(path))
        image = data[..., 0] if data.ndim == 3 else data
        masks = tifffile.imread(folder / f"{path.stem}_cp_masks.tif").astype(np.int32)
        cal = calibrate(
            image,
            masks=masks,
            microscope=Microscope(wavelength_um=0.55, modality="phase"),
            cell_width_um=1.0,
            crop_px=160,
            max_evaluations=25,
        )
        source = PipelineSource(export_settings(cal, n_items=n, seed=0))
        rows = []
        for unit in range(n):
            item = source.make_unit(unit)[0]
            rows.append(compare_images(image, masks, item.image, item.labels))
        real = rows[0]
        synth_cells = ", ".join(f"{c.cells[1]:.3f}" for c in rows)
        synth_bg = ", ".join(f"{c.background[1]:.3f}" for c in rows)
        print(
            f"| {path.stem} | {real.cells[0]:.3f} | {real.background[0]:.3f} | "
            f"{synth_cells} | {synth_bg} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
