"""Figure and numbers for docs/export.md, "Masks and images agree on what is visible".

Exports trench frames through the export pipeline (``PipelineSource``, the path
``napari-symbac export`` takes) with per-cell brightness variation off and at CV 0.8,
prints the distribution of per-cell contrast-to-noise (CNR) and draws frames holding
faint cells with their outlines coloured by CNR. Writes docs/images/visibility_cnr.png.
Run from the repository root: ``python docs/scripts/make_visibility_figure.py``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import imageio.v3 as iio
import numpy as np
from _args import script_parser
from skimage.segmentation import find_boundaries

from napari_symbac.export import ExportSettings, PipelineSource
from napari_symbac.settings import PipelineSettings

OUT = Path(__file__).resolve().parents[2] / "docs" / "images" / "visibility_cnr.png"
N_ITEMS = 60
#: Outline colour by CNR: below 1 (faint by default), 1-2, 2-3, 3 and above.
COLOURS = ((1.0, (1, 0, 0)), (2.0, (1, 0.5, 0)), (3.0, (1, 1, 0)), (np.inf, (0, 1, 0)))


def items(cv: float):
    pipeline = PipelineSettings()
    pipeline = dataclasses.replace(
        pipeline, render=dataclasses.replace(pipeline.render, cell_brightness_cv=cv)
    )
    settings = ExportSettings(n_items=N_ITEMS, first_frame=30, seed=3, pipeline=pipeline)
    source = PipelineSource(settings)
    return [item for unit in range(N_ITEMS) for item in source.make_unit(unit)]


def tile(item) -> np.ndarray:
    image = item.image.astype(float)
    low, high = np.percentile(image, [0.5, 99.5])
    grey = np.clip((image - low) / (high - low), 0, 1)
    plain = np.stack([grey] * 3, axis=-1)
    outlined = plain.copy()
    for cell, value in item.contrast_to_noise.items():
        colour = next(c for limit, c in COLOURS if value < limit)
        outlined[find_boundaries(item.labels == cell, mode="outer")] = colour
    gap = np.ones((plain.shape[0], 3, 3))
    return np.concatenate([plain, outlined, gap], axis=1)


def main() -> None:
    for cv in (0.0, 0.8):
        made = items(cv)
        values = np.array([v for it in made for v in it.contrast_to_noise.values()])
        shares = ", ".join(f"{np.mean(values < t):.1%} below {t:g}" for t in (1, 2, 3))
        print(
            f"CV {cv}: {values.size} cells in {len(made)} images; CNR min {values.min():.2f}, "
            f"median {np.median(values):.2f}; {shares}"
        )
    faint = [it for it in made if it.faint_cells][:8]
    figure = np.concatenate([tile(it) for it in faint], axis=1)
    figure = np.kron(figure, np.ones((2, 2, 1)))
    iio.imwrite(OUT, (figure * 255).astype(np.uint8))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    script_parser(__doc__).parse_args()  # no arguments; --help prints the docstring above
    main()
