"""Colony packing: measured on masks, matched by calibrate's choice of gravity."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import tifffile
from scipy import ndimage

from napari_symbac.calibrate.compaction import (
    MAX_OVERLAP_WIDTHS,
    PAD_PHYS_ITERS,
    choose_gravity,
    overlap_depths_um,
    trial,
)
from napari_symbac.calibrate.core import settings_from_fit
from napari_symbac.calibrate.measure import cell_curvatures_px, measure_field, measure_packing
from napari_symbac.fit.masks import estimate_pixel_size_um
from napari_symbac.settings import Camera, Microscope, RenderSettings
from napari_symbac.sim.cells import FrameCells


def _stack(gap_px: int) -> np.ndarray:
    """Six 8 x 30 px rods side by side, ``gap_px`` of background between them, and a
    lone rod far away (not a colony)."""
    masks = np.zeros((120, 120), np.int32)
    for k in range(6):
        r = 10 + k * (8 + gap_px)
        masks[r : r + 8, 10:40] = k + 1
    masks[100:108, 80:110] = 7
    return masks


def test_packing_of_touching_rods_is_full_and_seamless():
    p = measure_packing(_stack(0))
    assert p.n_colonies == 1  # the lone rod is not a colony
    assert p.cell_fraction == pytest.approx(1.0)
    assert p.mean_gap_px == 0.0
    assert p.touching_fraction == 1.0
    assert p.width_px == pytest.approx(7.0, abs=1.0)


def test_packing_sees_the_seams_of_a_looser_stack():
    tight, loose = measure_packing(_stack(0)), measure_packing(_stack(2))
    assert loose.n_colonies == 1  # gaps of 2 px are closed into one colony
    assert loose.mean_gap_px == pytest.approx(2.0, abs=0.1)
    assert loose.touching_fraction == 0.0
    # 6 x 240 px of cell in 6 x 240 + 5 x 60 px of colony
    assert loose.cell_fraction == pytest.approx(1440 / 1740, abs=0.02)
    assert loose.cell_fraction < tight.cell_fraction


def test_packing_refuses_empty_masks():
    with pytest.raises(ValueError, match="no cell"):
        measure_packing(np.zeros((20, 20), np.int32))


def test_curvature_of_a_straight_and_a_bent_rod():
    yy, xx = np.mgrid[0:200, 0:200].astype(float)
    straight = ((np.abs(yy - 50) < 4) & (np.abs(xx - 100) < 40)).astype(np.int32)
    radius = 80.0
    r = np.hypot(yy - 180.0, xx - 100.0)
    arc = (np.abs(r - radius) < 4) & (yy < 150) & (np.abs(xx - 100) < 40)
    bent = arc.astype(np.int32) * 2
    curv = cell_curvatures_px(straight + bent)
    assert curv[0] < 0.002
    assert curv[1] == pytest.approx(1 / radius, rel=0.25)


def test_overlap_depth_of_parallel_crossing_and_apart_cells():
    cells = FrameCells(
        ids=[1, 2, 3, 4, 5],
        x_um=[0.0, 0.8, 10.0, 10.0, 30.0],
        y_um=[0.0, 0.0, 0.0, 0.0, 0.0],
        angle_rad=[0.0, 0.0, 0.0, math.pi / 2, 0.0],
        length_um=[3.0, 3.0, 3.0, 3.0, 3.0],
        width_um=[1.0, 1.0, 1.0, 1.0, 1.0],
    )
    depths = np.sort(overlap_depths_um(cells))
    # 1 and 2 side by side 0.8 um apart: 0.2 um; 3 and 4 cross: a whole width
    assert depths == pytest.approx([0.2, 1.0])


@pytest.fixture(scope="module")
def colony_settings(real_data_dir):
    """Calibrate-style settings of Sample000033's colony, optics left at the defaults
    (the packing does not depend on them), and its masks."""
    masks = tifffile.imread(
        real_data_dir / "omnipose" / "Sample000033_cp_masks.tif"
    ).astype(np.int32)
    px = estimate_pixel_size_um(masks, 1.0)
    measurements = measure_field(np.zeros(masks.shape), masks)
    settings, _ = settings_from_fit(
        measurements, Microscope(pixel_size_um=px), RenderSettings(upsample=1), Camera()
    )
    simulation = dataclasses.replace(settings.simulation, phys_iters=PAD_PHYS_ITERS)
    return dataclasses.replace(settings, simulation=simulation), masks


def test_calibrate_picks_a_denser_colony_for_a_denser_input(colony_settings):
    settings, masks = colony_settings
    dense = measure_packing(masks)
    # the same colony with a 2 px seam opened around every cell
    shrunk = np.where(ndimage.grey_erosion(masks, size=5) == masks, masks, 0)
    loose = measure_packing(shrunk)
    assert dense.cell_fraction > 0.95 > loose.cell_fraction
    g_dense, trials = choose_gravity(settings, dense, candidates=(0.0, 8.0, 16.0))
    g_loose, _ = choose_gravity(settings, loose, candidates=(0.0, 8.0, 16.0))
    assert g_dense > g_loose
    by_gravity = {t.gravity: t for t in trials}
    assert (
        by_gravity[g_dense].packing.cell_fraction > by_gravity[g_loose].packing.cell_fraction
    )
    assert by_gravity[g_dense].overlap_widths <= MAX_OVERLAP_WIDTHS
    # gravity compacts the simulated colony
    assert by_gravity[16.0].packing.cell_fraction > by_gravity[0.0].packing.cell_fraction
    assert by_gravity[16.0].packing.mean_gap_px < by_gravity[0.0].packing.mean_gap_px


def test_choose_gravity_is_deterministic(colony_settings):
    settings, masks = colony_settings
    target = measure_packing(masks)
    first = choose_gravity(settings, target, candidates=(0.0, 8.0))
    second = choose_gravity(settings, target, candidates=(0.0, 8.0))
    assert first[0] == second[0]
    assert [t.packing.cell_fraction for t in first[1]] == [
        t.packing.cell_fraction for t in second[1]
    ]


def test_choose_gravity_stops_when_cancelled(colony_settings):
    """The Calibrate dock's Cancel during the packing search: asked before each trial."""
    from napari_symbac.fit import FitCancelled

    settings, masks = colony_settings
    asked = []

    def cancel_at_the_second():
        asked.append(True)
        return len(asked) > 1

    with pytest.raises(FitCancelled, match="calibration cancelled"):
        choose_gravity(
            settings, measure_packing(masks), candidates=(0.0, 8.0), cancel=cancel_at_the_second
        )
    assert len(asked) == 2  # one trial ran, the second was not started


def test_bent_cells_read_more_curved_than_straight_ones(colony_settings):
    settings, _ = colony_settings
    bent = dataclasses.replace(
        settings, simulation=dataclasses.replace(settings.simulation, do_transformation=True)
    )
    straight_trial, bent_trial = trial(settings, 8.0), trial(bent, 8.0)
    assert bent_trial.median_curvature_px > 1.5 * straight_trial.median_curvature_px
    assert straight_trial.median_length_px > 0
