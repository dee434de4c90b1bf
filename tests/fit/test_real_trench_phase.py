"""The partially coherent model fitted to the real SyMBac trench (GPL-2 sample data, read only)."""

from __future__ import annotations

import dataclasses

import pytest
import tifffile

from napari_symbac.fit import fit_parameters, fit_scene, fitted_pipeline
from napari_symbac.fit.fitted_settings import fitted_render
from napari_symbac.settings import Microscope, RenderSettings, SimulationSettings

MICROSCOPE = Microscope(pixel_size_um=0.065)  # 100x oil, NA 1.45, Ph3
FIVE = (
    "cell_phase_rad",
    "device_phase_rad",
    "apodisation_sigma_um",
    "phase_ring_width_scale",
    "defocus_sigma_um",
)


@pytest.mark.slow
def test_transparent_cells_and_pdms_fit_the_trench_inside_every_bound(real_data_dir):
    # the trench's closed end and first cell: 96 of its 256 rows
    image = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")[:96]
    linear = fit_scene(image, MICROSCOPE, RenderSettings(), None, closed_end="round")
    # the settings that draw matched data, in Python as `fit` writes them; the trench of
    # these 96 rows (4.8 um) is shorter than its cells divide, so it is not simulated
    settings, notes = fitted_pipeline(linear, image, MICROSCOPE)
    assert settings.render == fitted_render(linear, "phase")
    assert settings.camera == linear.camera
    assert settings.microscope == MICROSCOPE
    [note] = notes
    assert note.startswith("simulation settings kept from the config: cell_max_length_um=")
    assert "must be shorter than the trench (length_um=4.8" in note
    assert settings.simulation == SimulationSettings()
    assert linear.trench_geometry(image.shape, 0.065).length_um < 5
    level = linear.render.media_intensity
    start = dataclasses.replace(
        linear.render, phase_model="partially_coherent", source_points=16,
        cell_phase_rad=0.9, device_phase_rad=1.0, apodisation_sigma_um=1.5,
        phase_ring_width_scale=1.5, defocus_sigma_um=0.05,
        cell_intensity=level, device_intensity=level,  # B = 1: pure phase objects
    )  # fmt: skip
    result = fit_parameters(
        image, None, linear.scene, MICROSCOPE, start, linear.camera, terms=("pixel",),
        fit=FIVE, max_evaluations=60, global_search=False,
    )  # fmt: skip
    r = result.render
    assert result.warnings == ()  # no parameter at a bound, better than its start
    assert result.objective_after < 0.05 * result.objective_before
    # the plate's ring a little wider than the catalogue annulus, well inside [0.5, 3]
    assert 1.0 < r.phase_ring_width_scale < 2.5
    # the transmissions stayed those of transparent cells and PDMS
    assert r.cell_intensity == pytest.approx(r.media_intensity)
    assert r.device_intensity == pytest.approx(r.media_intensity)
