"""Sample data for napari's File > Open Sample menu (no Qt, no napari import)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from napari_symbac.settings import PipelineSettings

__all__ = ["colicoords_field", "synthetic_trench"]

SAMPLE_FRAMES = 24
SAMPLE_SEED = 2024


def synthetic_trench() -> list[tuple]:
    """A rendered mother-machine trench time series with its instance masks.

    Returns napari layer-data tuples: the ``(T, Y, X)`` phase-contrast image and the
    matching labels (values are cell ids, consistent over time), both scaled to
    micrometres.
    """
    from napari_symbac.pipeline import render_simulation
    from napari_symbac.sim import simulate

    defaults = PipelineSettings()
    settings = dataclasses.replace(
        defaults,
        simulation=dataclasses.replace(
            defaults.simulation, n_frames=SAMPLE_FRAMES, seed=SAMPLE_SEED
        ),
    )
    simulation = simulate(settings.simulation)
    series = render_simulation(simulation, settings)
    pixel = settings.microscope.pixel_size_um
    scale = (1.0, pixel, pixel)
    return [
        (series.images, {"name": "synthetic trench", "scale": scale}, "image"),
        (series.labels, {"name": "synthetic trench labels", "scale": scale}, "labels"),
    ]


def colicoords_field() -> list[tuple]:
    """A real agar-pad field of E. coli: brightfield, fluorescence and cell masks.

    From the ColiCoords test data (MIT licence; see ``sample_data/README.md``).
    """
    from napari_symbac.io import read_recording

    folder = Path(__file__).parent / "sample_data"
    brightfield = read_recording(folder / "colicoords_brightfield.tif")
    fluorescence = read_recording(folder / "colicoords_fluorescence.tif")
    masks = read_recording(folder / "colicoords_binary.tif")
    scale = (brightfield.pixel_size_um,) * 2
    return [
        (brightfield.data, {"name": "ColiCoords brightfield", "scale": scale}, "image"),
        (
            fluorescence.data,
            {
                "name": "ColiCoords fluorescence",
                "scale": scale,
                "colormap": "green",
                "blending": "additive",
                "visible": False,
            },
            "image",
        ),
        (masks.data, {"name": "ColiCoords cells", "scale": scale, "opacity": 0.4}, "labels"),
    ]
