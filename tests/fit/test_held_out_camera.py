"""A scene fit on a held-out half of the pixels keeps the camera measured from the image."""

from __future__ import annotations

import numpy as np
from _fit_synthetic import TRUTH

from napari_symbac.fit import fit_scene
from napari_symbac.fit.camera_estimate import estimate_camera
from napari_symbac.settings import Camera


def test_a_held_out_checkerboard_keeps_the_measured_camera(truth):
    """Fitting one half of a pixel checkerboard: photon transfer needs whole 3 x 3
    neighbourhoods, so it measures the camera on every unclipped pixel instead of
    falling back to the residual (whose camera would absorb any misfit)."""
    rows, cols = truth.image.shape
    ii, jj = np.mgrid[:rows, :cols]
    half = (ii + jj) % 2 == 0
    fit = fit_scene(
        truth.image, truth.microscope, TRUTH, None, valid=half, moves=False, irls_rounds=1
    )
    whole = estimate_camera(truth.image, camera=Camera(baseline_adu=fit.camera.baseline_adu))
    assert fit.camera.sensitivity_adu_per_e == whole.camera.sensitivity_adu_per_e
    assert abs(fit.camera.sensitivity_adu_per_e / truth.camera.sensitivity_adu_per_e - 1) < 0.2
    assert 0.85 < fit.objective_after < 1.15
