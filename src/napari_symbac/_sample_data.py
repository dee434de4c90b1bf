"""Sample data for napari's File > Open Sample menu (no Qt, no napari import)."""

from __future__ import annotations

import dataclasses

from napari_symbac.settings import PipelineSettings

__all__ = ["synthetic_trench"]

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
