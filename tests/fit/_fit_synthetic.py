"""Helpers: synthetic trenches rendered by the project's own model, with known parameters."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from napari_symbac.optics import ForwardModel
from napari_symbac.scene import Scene, draw_scene
from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry
from napari_symbac.sim import FrameCells

PIXEL_UM = 0.065
#: A 128 x 46 crop of a 1.5 um trench with 0.75 um of PDMS either side.
TRENCH = TrenchGeometry(length_um=128 * PIXEL_UM - 0.75, width_um=1.5, depth_um=1.2, margin_um=0.75)
#: Truth: ~900 e- of media background at 2.9 ADU/e- (camera noise, eq. 17).
TRUTH = RenderSettings(
    cell_intensity=1400.0,
    media_intensity=2600.0,
    device_intensity=900.0,
    apodisation_sigma_um=0.6,
    defocus_sigma_um=0.15,
    ring_contrast=0.5,
    psf_offset=0.05,
)
#: A deliberately wrong start: intensities 20 % off, apodisation and defocus far away.
START = RenderSettings(
    cell_intensity=1700.0,
    media_intensity=2100.0,
    device_intensity=1100.0,
    apodisation_sigma_um=1.2,
    defocus_sigma_um=0.0,
    psf_offset=0.0,
)


@dataclass(frozen=True)
class Truth:
    cells: FrameCells
    scene: Scene
    image: np.ndarray
    microscope: Microscope
    render: RenderSettings
    camera: Camera


def make_cells(y_um, x_um=None, angle_rad=None, length_um=None, width_um=0.95) -> FrameCells:
    n = len(y_um)
    return FrameCells(
        ids=np.arange(1, n + 1),
        x_um=np.full(n, 0.75) if x_um is None else np.asarray(x_um, float),
        y_um=np.asarray(y_um, float),
        angle_rad=np.zeros(n) if angle_rad is None else np.asarray(angle_rad, float),
        length_um=np.full(n, 2.4) if length_um is None else np.asarray(length_um, float),
        width_um=np.full(n, width_um),
    )


def make_truth(seed: int = 1) -> Truth:
    """Three cells in a 128 x 46 trench crop, rendered with :data:`TRUTH` and camera noise."""
    cells = make_cells(
        y_um=[1.3, 3.9, 6.55],
        x_um=[0.74, 0.78, 0.72],
        angle_rad=[0.0, 0.08, -0.05],
        length_um=[2.3, 2.6, 2.2],
    )
    microscope = Microscope(pixel_size_um=PIXEL_UM)
    camera = Camera()
    scene = draw_scene(cells, TRENCH, microscope, TRUTH)
    image = ForwardModel(microscope, TRUTH, camera).render(scene, np.random.default_rng(seed))
    return Truth(cells, scene, image, microscope, TRUTH, camera)


#: Fluorescence truth: bright cells (2000 ADU) on a dim background (150 ADU).
FLUO_TRUTH = RenderSettings(
    cell_intensity=2000.0,
    media_intensity=150.0,
    device_intensity=0.0,
    defocus_sigma_um=0.1,
)


def make_fluorescence_field(seed: int = 2, shape: tuple[int, int] = (96, 96)) -> Truth:
    """Four cells on an open 96 x 96 field (80 nm pixels), fluorescence, camera noise."""
    microscope = Microscope(pixel_size_um=0.08, modality="fluorescence")
    return _open_field(microscope, FLUO_TRUTH, seed, shape)


def _open_field(
    microscope: Microscope, render: RenderSettings, seed: int, shape: tuple[int, int]
) -> Truth:
    """The four cells of the open-field tests (0.9 um wide) rendered with camera noise."""
    from napari_symbac.scene import Field

    cells = make_cells(
        y_um=[1.8, 2.2, 5.4, 5.6],
        x_um=[1.6, 5.4, 2.0, 5.8],
        angle_rad=[0.3, -0.5, 1.2, 0.05],
        length_um=[2.6, 2.2, 3.0, 2.4],
        width_um=0.9,
    )
    camera = Camera()
    field = Field(shape[1] * microscope.pixel_size_um, shape[0] * microscope.pixel_size_um)
    scene = draw_scene(cells, TrenchGeometry(), microscope, render, field=field)
    image = ForwardModel(microscope, render, camera).render(scene, np.random.default_rng(seed))
    return Truth(cells, scene, image, microscope, render, camera)


def make_fluorescence_series(n_frames: int = 3, seed: int = 5) -> list[Truth]:
    """Frames of one recording: four growing, drifting cells per frame, one optics.

    Frame ``t`` holds the cells of :func:`make_fluorescence_field` moved by
    ``(0.25 t, 0.15 t)`` um, turned by ``0.1 t`` rad and ``0.15 t`` um longer, rendered
    with :data:`FLUO_TRUTH` and the same camera, each frame with its own noise.
    """
    from napari_symbac.scene import Field

    microscope = Microscope(pixel_size_um=0.08, modality="fluorescence")
    camera = Camera()
    field = Field(96 * 0.08, 96 * 0.08)
    model = ForwardModel(microscope, FLUO_TRUTH, camera)
    rng = np.random.default_rng(seed)
    frames = []
    for t in range(n_frames):
        cells = make_cells(
            y_um=np.array([1.8, 2.2, 5.4, 5.6]) + 0.15 * t,
            x_um=np.array([1.6, 5.4, 2.0, 5.8]) + 0.25 * t,
            angle_rad=np.array([0.3, -0.5, 1.2, 0.05]) + 0.1 * t,
            length_um=np.array([2.2, 2.0, 2.6, 2.2]) + 0.15 * t,
            width_um=0.9,
        )
        scene = draw_scene(cells, TrenchGeometry(), microscope, FLUO_TRUTH, field=field)
        frames.append(
            Truth(cells, scene, model.render(scene, rng), microscope, FLUO_TRUTH, camera)
        )
    return frames


#: Bright-field truth: cells that absorb 4 % of the light and are seen 0.3 um out of
#: focus (the lens term, kappa 0.015 um^2, as fitted on ColiCoords' crop 01).
BRIGHTFIELD_TRUTH = RenderSettings(
    cell_intensity=2500.0,
    media_intensity=2600.0,
    device_intensity=0.0,
    defocus_sigma_um=0.1,
    defocus_contrast_um2=0.015,
)


def make_brightfield_field(seed: int = 4, shape: tuple[int, int] = (96, 96)) -> Truth:
    """The four cells of :func:`make_fluorescence_field` in bright field, camera noise."""
    microscope = Microscope(pixel_size_um=0.08, numerical_aperture=1.4, modality="brightfield")
    return _open_field(microscope, BRIGHTFIELD_TRUTH, seed, shape)
