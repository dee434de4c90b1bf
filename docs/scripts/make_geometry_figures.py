"""Figure for docs/rendering.md, "2D geometries": rendered chamber, agar pad, outline.

Simulates each geometry, draws it through ``napari_symbac.pipeline`` (the path every
caller uses) and renders phase contrast; the agar pad is also shown in fluorescence
with per-cell brightness (section 13.2.2). Writes docs/images/geometries_rendered.png.
Run from the repository root: ``python docs/scripts/make_geometry_figures.py``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import matplotlib
from _args import script_parser

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from napari_symbac.optics import ForwardModel
from napari_symbac.pipeline import draw_frame, noise_rng
from napari_symbac.settings import (
    AgarPadGeometry,
    OutlineGeometry,
    PipelineSettings,
    RenderSettings,
    SimulationSettings,
    TrenchGeometry,
)
from napari_symbac.sim import simulate

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "images"

#: Phase contrast of the agar pad: PSF offset for halo / shade-off, Perlin texture.
PAD_RENDER = RenderSettings(psf_offset=0.05, texture_amplitude=0.05)
#: A user's device: a chamber with a pillar, open at the bottom (polylines in um).
OUTLINE = OutlineGeometry(
    polylines_um=(
        ((0.0, 14.0), (0.0, 0.0), (12.0, 0.0), (12.0, 14.0)),
        ((5.0, 7.0), (7.0, 7.0), (7.0, 9.0), (5.0, 9.0), (5.0, 7.0)),
    ),
    founders_um=((3.0, 2.0), (9.0, 2.0)),
    exit_margin_um=1.0,
)


def _render(simulation, render: RenderSettings, *, fluorescence: bool = False):
    settings = PipelineSettings(simulation=simulation.settings, render=render)
    if fluorescence:
        settings = dataclasses.replace(
            settings,
            microscope=dataclasses.replace(settings.microscope, modality="fluorescence"),
            render=dataclasses.replace(settings.render, cell_brightness_cv=0.4),
        )
    index = len(simulation.frames) - 1
    scene = draw_frame(simulation, settings, index)
    rng = noise_rng(settings)
    model = ForwardModel(settings.microscope, settings.render, settings.camera)
    return model.render(scene, rng, cache=False), scene.camera_labels()


def _show(ax, image, labels, title):
    low, high = np.percentile(image, [0.5, 99.5])
    ax.imshow(np.clip((image - low) / (high - low), 0, 1), cmap="gray")
    n_cells = len(np.unique(labels)) - 1
    title = f"{title}\n{image.shape[1]} x {image.shape[0]} px, {n_cells} cells"
    ax.set_title(title, fontsize=9, loc="left")
    ax.set_xticks([])
    ax.set_yticks([])


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    chamber = simulate(
        SimulationSettings(
            geometry="chamber",
            n_frames=70,
            n_founders=3,
            trench=TrenchGeometry(length_um=12.0, width_um=10.0),
            seed=1,
        )
    )
    pad = simulate(
        SimulationSettings(
            geometry="agar_pad", n_frames=44, agar_pad=AgarPadGeometry(25.0, 25.0), seed=2024
        )
    )
    device = simulate(SimulationSettings(geometry="outline", n_frames=70, outline=OUTLINE, seed=7))

    panels = [
        (*_render(chamber, RenderSettings()), "chamber (13.1): a wide trench"),
        (*_render(pad, PAD_RENDER), "agar pad, phase (13.2.1): halo, texture"),
        (
            *_render(
                pad,
                RenderSettings(cell_intensity=3000.0, media_intensity=150.0, device_intensity=0.0),
                fluorescence=True,
            ),
            "agar pad, fluorescence (13.2.2)",
        ),
        (*_render(device, RenderSettings()), "outline: user's walls as PDMS"),
    ]
    fig, axes = plt.subplots(1, 4, figsize=(13, 3.9))
    for ax, (image, labels, title) in zip(axes, panels):
        _show(ax, image.astype(float), labels, title)
    fig.tight_layout()
    path = OUT / "geometries_rendered.png"
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    print(f"wrote {path}")


if __name__ == "__main__":
    script_parser(__doc__).parse_args()  # no arguments; --help prints the docstring above
    main()
