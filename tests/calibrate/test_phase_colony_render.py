"""Calibrated phase colonies render the optics as fitted: the drawn cells carry the phase
fitted on the masks' scene, and the export keeps the cells' bright-field transmission."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from napari_symbac.export.dataset import PHASE_TRANSMISSION_SCALE, export_of
from napari_symbac.fit.fitted_settings import drawn_colony_phase
from napari_symbac.optics import ForwardModel
from napari_symbac.scene import draw_scene, field_of, scene_from_masks
from napari_symbac.settings import (
    AgarPadGeometry,
    Camera,
    Microscope,
    PipelineSettings,
    RenderSettings,
    SimulationSettings,
)
from napari_symbac.sim.cells import FrameCells

MIC = Microscope(pixel_size_um=0.08, wavelength_um=0.55, modality="phase")
RENDER = RenderSettings(
    upsample=1,
    psf_radius_px=24,
    phase_model="partially_coherent",
    cell_intensity=100.0,
    media_intensity=100.0,
    device_intensity=100.0,
    cell_phase_rad=0.5,
    source_points=8,
    noise_model="none",
)


def _pad_settings(width_um: float) -> PipelineSettings:
    simulation = SimulationSettings(
        geometry="agar_pad",
        agar_pad=AgarPadGeometry(field_width_um=6.0, field_height_um=6.0, edge_margin_um=1.0),
        cell_width_um=width_um,
    )
    return PipelineSettings(simulation=simulation, microscope=MIC, render=RENDER, camera=Camera())


def _one_cell(width_um: float) -> FrameCells:
    return FrameCells(
        ids=np.array([1]),
        x_um=np.array([3.0]),
        y_um=np.array([3.0]),
        angle_rad=np.array([0.3]),
        length_um=np.array([3.0]),
        width_um=np.array([width_um]),
    )


@pytest.mark.parametrize("width_um", [0.9, 1.1])
def test_drawn_cell_carries_the_phase_fitted_on_its_masks(width_um):
    settings = _pad_settings(width_um)
    depth = settings.simulation.trench.depth_um
    assert depth != pytest.approx(width_um)  # the pad is deeper or shallower than the cell
    drawn_settings, note = drawn_colony_phase(settings)
    assert drawn_settings.render.cell_phase_rad == pytest.approx(0.5 * depth / width_um)
    assert "pad depth" in note
    drawn = draw_scene(
        _one_cell(width_um), settings.simulation.trench, MIC, RENDER,
        field=field_of(settings.simulation),
    )  # fmt: skip
    labels = drawn.camera_labels().astype(np.int64)
    masks_scene = scene_from_masks(labels, MIC, RENDER)
    # peak optical path: the masks' chord is 1 on the centre line, the drawn one w / D
    fitted_peak = RENDER.cell_phase_rad * float(masks_scene.cells.max())
    drawn_peak = drawn_settings.render.cell_phase_rad * float(drawn.cells.max())
    assert drawn_peak == pytest.approx(fitted_peak, rel=0.03)

    def cell_median(scene, render):
        image = ForwardModel(MIC, render, Camera()).render_clean(scene)
        return float(np.median(np.asarray(image)[labels > 0]))

    reference = cell_median(masks_scene, RENDER)  # what the fit saw
    rescaled = abs(cell_median(drawn, drawn_settings.render) - reference)
    as_fitted = abs(cell_median(drawn, RENDER) - reference)
    assert rescaled < 0.5 * as_fitted


def test_partially_coherent_export_keeps_the_cells_transmission(real_data_dir):
    """Items of a dense phase colony draw the cells' transmission B = I_c / I_m within
    its physical range (never above 1) and keep the media level; a linear-model
    calibration keeps SyMBac's sweep."""
    from napari_symbac.calibrate import Calibration, export_settings, measure_field
    from napari_symbac.export.dataset import Randomisation

    masks = np.zeros((40, 40), np.int32)
    masks[10:18, 5:30] = 1
    measurements = measure_field(np.zeros(masks.shape), masks)
    settings = dataclasses.replace(_pad_settings(1.0), camera=Camera(bit_depth=8))

    def calibration(render):
        return Calibration(
            settings=dataclasses.replace(settings, render=render),
            measurements=measurements,
            reference=np.zeros(masks.shape),
            masks=masks,
            crop=(slice(0, 40), slice(0, 40)),
            method="test",
            fit_chi2=(1.0, 1.0),
        )

    rng = np.random.default_rng(0)
    coherent = export_settings(calibration(RENDER), n_items=4, seed=0)
    transmissions = []
    for _ in range(16):
        drawn = coherent.randomise.draw(rng, coherent.pipeline)
        assert drawn["render.media_intensity"] == RENDER.media_intensity
        transmissions.append(drawn["render.cell_intensity"] / drawn["render.media_intensity"])
    assert max(transmissions) <= 1.0
    assert min(transmissions) >= PHASE_TRANSMISSION_SCALE[0]
    assert max(transmissions) - min(transmissions) > 0.1  # still varied between images
    # the default export of such settings (`export --config FIT/settings.yaml`) alike
    # (found as a user: a colony fit's settings drew B up to 1.28)
    assert export_of(coherent.pipeline).randomise == coherent.randomise
    linear = export_settings(
        calibration(dataclasses.replace(RENDER, phase_model="linear")), n_items=4, seed=0
    )
    assert linear.randomise.cell_intensity_scale == Randomisation().cell_intensity_scale
