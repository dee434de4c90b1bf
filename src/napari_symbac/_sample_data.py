"""Sample data for napari's File > Open Sample menu (no Qt, no napari import)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from napari_symbac.io import SYMBAC_METADATA_KEY, layer_axes
from napari_symbac.settings import PipelineSettings

__all__ = ["colicoords_field", "synthetic_agar_pad", "synthetic_trench"]

SAMPLE_FRAMES = 24
SAMPLE_SEED = 2024
#: Frames simulated for the agar-pad sample (one founder grows to ~80 cells) and how
#: many of the last ones are rendered.
AGAR_PAD_FRAMES = 44
AGAR_PAD_SHOWN = 3


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
    axes = layer_axes(settings.microscope.pixel_size_um, 3)
    # a rendered layer as Simulate makes one: Tune tunes it, Export exports its settings
    rendered = {SYMBAC_METADATA_KEY: {"simulation": simulation, "settings": settings}}
    return [
        (series.images, {"name": "synthetic trench", **axes, "metadata": rendered}, "image"),
        (series.labels, {"name": "synthetic trench labels", **axes}, "labels"),
    ]


def synthetic_agar_pad() -> list[tuple]:
    """A rendered agar-pad colony (supplement 13.2): the last few frames, with masks.

    One founder grows into a monolayer colony of about 80 cells in a 25 x 25 um field;
    the last frames are rendered in phase contrast with a small PSF offset (halo and
    shade-off) and a Perlin background texture. Returns napari layer-data tuples: the
    ``(T, Y, X)`` image and its labels (values are cell ids), scaled to micrometres.
    """
    from napari_symbac.optics import ForwardModel
    from napari_symbac.pipeline import draw_frame, noise_rng
    from napari_symbac.settings import AgarPadGeometry
    from napari_symbac.sim import simulate

    defaults = PipelineSettings()
    settings = dataclasses.replace(
        defaults,
        simulation=dataclasses.replace(
            defaults.simulation,
            geometry="agar_pad",
            agar_pad=AgarPadGeometry(25.0, 25.0),
            n_frames=AGAR_PAD_FRAMES,
            seed=SAMPLE_SEED,
        ),
        render=dataclasses.replace(defaults.render, psf_offset=0.05, texture_amplitude=0.05),
    )
    simulation = simulate(settings.simulation)
    model = ForwardModel(settings.microscope, settings.render, settings.camera)
    rng = noise_rng(settings)
    images, labels = [], []
    for index in range(AGAR_PAD_FRAMES - AGAR_PAD_SHOWN, AGAR_PAD_FRAMES):
        scene = draw_frame(simulation, settings, index)
        images.append(model.render(scene, rng, cache=False))
        labels.append(scene.camera_labels())
    axes = layer_axes(settings.microscope.pixel_size_um, 3)
    # its settings for Export; no simulation, as the layer shows only its last frames
    rendered = {SYMBAC_METADATA_KEY: {"settings": settings}}
    return [
        (np.stack(images), {"name": "synthetic agar pad", **axes, "metadata": rendered}, "image"),
        (np.stack(labels), {"name": "synthetic agar pad labels", **axes}, "labels"),
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
    axes = layer_axes(brightfield.pixel_size_um, 2)
    # the fluorescence first, with its modality: the Recording dock takes the first image
    # (found as a user: it took the brightfield and called it phase contrast with a Ph3
    # condenser); the brightfield is marked as such, for a user who chooses it
    return [
        (
            fluorescence.data,
            {
                "name": "ColiCoords fluorescence",
                **axes,
                "colormap": "green",
                "metadata": {
                    "pixel_size_um": fluorescence.pixel_size_um,
                    "modality": "fluorescence",
                },
            },
            "image",
        ),
        (
            brightfield.data,
            {
                "name": "ColiCoords brightfield",
                **axes,
                "visible": False,
                "metadata": {
                    "pixel_size_um": brightfield.pixel_size_um,
                    "modality": "brightfield",
                },
            },
            "image",
        ),
        (masks.data, {"name": "ColiCoords cells", **axes, "opacity": 0.4}, "labels"),
    ]
