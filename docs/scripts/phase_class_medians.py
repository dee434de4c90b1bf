"""Issue 16's table for calibrated synthetic colonies: normalised class medians, real vs synthetic.

Run: ``python docs/scripts/phase_class_medians.py REAL_DATA_DIR [N_SYNTHETIC [FIGURE]]``. For each
Omnipose colony (MIT, ``REAL_DATA_DIR/omnipose``): ``calibrate`` with its masks exactly as
``benchmarks/bench_transfer.py`` does (pixel size from the masks and a 1 um width, 0.55 um
light, a 160 px crop, 25 renders), then ``N_SYNTHETIC`` images of the matched dataset, each
compared with the real image by ``calibrate.compare_images`` (1-99 percentile normalisation;
cells = mask > 0, background = more than 6 px from every cell). Prints one row per image.

The last two columns separate the optics from the layout: the real image's own masks
(:func:`~napari_symbac.scene.scene_from_masks`) rendered with the optics as fitted (seed
0 noise), so that what differs from the real image there is the model, and what differs
between them and the dataset's images is the simulated layout. With ``FIGURE`` (a PNG
path) it also draws, one row per image, the real image, the first synthetic image and the
real masks rendered with the fitted optics, each at its own 1-99 percentiles (the
normalisation the medians are taken at).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import tifffile
from _args import add_real_data, checked_real_data, script_parser

from napari_symbac.calibrate import calibrate, compare_images, export_settings
from napari_symbac.export.dataset import PipelineSource
from napari_symbac.optics import ForwardModel
from napari_symbac.scene import scene_from_masks
from napari_symbac.settings import Microscope


def calibrated_colony(path: Path):
    """An Omnipose colony (grey image, its masks) and its ``calibrate`` result as
    ``benchmarks/bench_transfer.py`` makes it (0.55 um, 1 um cells, 160 px crop, 25
    renders)."""
    data = np.asarray(iio.imread(path))
    image = data[..., 0] if data.ndim == 3 else data
    masks = tifffile.imread(path.parent / f"{path.stem}_cp_masks.tif").astype(np.int32)
    cal = calibrate(
        image,
        masks=masks,
        microscope=Microscope(wavelength_um=0.55, modality="phase"),
        cell_width_um=1.0,
        crop_px=160,
        max_evaluations=25,
    )
    return image, masks, cal


def on_real_masks(cal, masks: np.ndarray) -> np.ndarray:
    """The real masks' scene rendered with the optics fitted to it (the phase as fitted
    per unit of the masks' material, before it is rescaled for the drawn pad)."""
    s = cal.settings
    depth, width = s.simulation.trench.depth_um, s.simulation.cell_width_um
    render = dataclasses.replace(s.render, cell_phase_rad=s.render.cell_phase_rad * width / depth)
    model = ForwardModel(s.microscope, render, s.camera)
    return model.render(scene_from_masks(masks, s.microscope, render), np.random.default_rng(0))


def figure(rows: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]], path: Path) -> None:
    """Real | synthetic | real masks with the fitted optics, each normalised to 1-99 %."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from napari_symbac.fit.masks import normalise_percentiles

    fig, axes = plt.subplots(len(rows), 3, figsize=(12, 3.9 * len(rows)))
    for (name, real, synthetic, own), ax in zip(rows, np.atleast_2d(axes), strict=True):
        titles = (f"{name}: real", "calibrated synthetic (dataset item 0)",
                  "real masks, fitted optics")  # fmt: skip
        for a, image, title in zip(ax, (real, synthetic, own), titles, strict=True):
            a.imshow(normalise_percentiles(image), cmap="gray", vmin=0, vmax=1)
            a.set_title(title, fontsize=9, loc="left")
            a.set_xticks([])
            a.set_yticks([])
    fig.tight_layout()
    fig.savefig(path, dpi=70)
    plt.close(fig)
    from PIL import Image

    Image.open(path).convert("RGB").quantize(256).save(path, optimize=True)  # a third the bytes


def main(real: Path, n: int = 2, picture: Path | None = None) -> None:
    folder = real / "omnipose"
    panels = []
    print(
        "| image | real cells | real background | synthetic cells | synthetic background | "
        "fitted optics on the real masks: cells | background |"
    )
    print("|---|---|---|---|---|---|---|")
    for path in sorted(folder.glob("Sample*.png")):
        image, masks, cal = calibrated_colony(path)
        source = PipelineSource(export_settings(cal, n_items=n, seed=0))
        rows, first = [], None
        for unit in range(n):
            item = source.make_unit(unit)[0]
            first = item.image if first is None else first
            rows.append(compare_images(image, masks, item.image, item.labels))
        real = rows[0]
        own_image = on_real_masks(cal, masks)
        own = compare_images(image, masks, own_image, masks)
        panels.append((path.stem, image, first, own_image))
        synth_cells = ", ".join(f"{c.cells[1]:.3f}" for c in rows)
        synth_bg = ", ".join(f"{c.background[1]:.3f}" for c in rows)
        print(
            f"| {path.stem} | {real.cells[0]:.3f} | {real.background[0]:.3f} | "
            f"{synth_cells} | {synth_bg} | {own.cells[1]:.3f} | {own.background[1]:.3f} |",
            flush=True,
        )
    if picture is not None:
        figure(panels, picture)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line: ``REAL_DATA_DIR [N_SYNTHETIC [FIGURE]]``."""
    parser = script_parser(__doc__)
    add_real_data(
        parser, required=True, help="the folder of the project's real recordings (omnipose inside)"
    )
    parser.add_argument(
        "n",
        nargs="?",
        type=int,
        default=2,
        metavar="N_SYNTHETIC",
        help="images of each matched dataset to compare (default: 2)",
    )
    parser.add_argument(
        "picture", nargs="?", type=Path, metavar="FIGURE", help="a PNG to draw the rows into"
    )
    args = parser.parse_args(argv)
    checked_real_data(parser, args.real / "omnipose", "the Omnipose colonies")
    return args


if __name__ == "__main__":
    args = parse_args()
    main(args.real, args.n, args.picture)
