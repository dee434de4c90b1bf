"""The illumination surface as a stage of the scene fit (fit/illumination.py, engine)."""

from __future__ import annotations

import numpy as np
import pytest
from _fit_synthetic import TRENCH, TRUTH, make_truth

from napari_symbac.diagnose import stage_for
from napari_symbac.diagnose.effects.uneven_illumination import _basis as diagnosis_basis
from napari_symbac.fit import fit_scene
from napari_symbac.fit.engine import Layout, SceneModel
from napari_symbac.fit.illumination import (
    illumination_basis,
    illumination_stage,
    illumination_terms,
)
from napari_symbac.fit.placement import TrenchPlacement
from napari_symbac.optics import ForwardModel
from napari_symbac.settings import Camera

#: A surface of degree 2: 12 % brighter at the bottom of the crop, dimmer at both ends.
TRUE_LIGHT = np.array([0.04, 0.12, 0.0, -0.10, 0.03])


def test_degree_two_is_the_diagnosis_surface():
    shape = (40, 23)
    rows, cols = shape
    yn = np.broadcast_to(np.linspace(-1, 1, rows)[:, None], shape)
    xn = np.broadcast_to(np.linspace(-1, 1, cols)[None, :], shape)
    np.testing.assert_allclose(illumination_basis(shape, 2), diagnosis_basis(yn, xn), atol=1e-12)
    assert illumination_terms(2) == ("x", "y", "x^2", "y^2", "xy")
    # so the fitted coefficients render the same through the diagnosis' stage
    image = np.full(shape, 1000.0, np.float32)
    ours = illumination_stage(TRUE_LIGHT, 2).apply(image, None)
    theirs = stage_for("uneven_illumination", {"coefficients": TRUE_LIGHT.tolist()}).apply(
        image, None
    )
    np.testing.assert_allclose(ours, theirs, rtol=1e-6)


def test_terms_by_degree_and_bad_orders():
    assert illumination_terms(0) == ()
    assert len(illumination_terms(4)) == 14
    assert illumination_terms(3)[5:] == ("x^3", "y^3", "x^2y", "xy^2")
    basis = illumination_basis((64, 30), 4)
    np.testing.assert_allclose(basis.mean(axis=(1, 2)), 0, atol=1e-12)  # centred
    for bad in (-1, 7, 2.5):
        with pytest.raises(ValueError, match="illumination_order must be an integer"):
            illumination_terms(bad)
    with pytest.raises(ValueError, match="needs 5 coefficients"):
        illumination_stage(np.zeros(3), 2)


def _lit_model(truth, order=2):
    placement = TrenchPlacement(TRENCH.margin_um, TRENCH.width_um, TRENCH.margin_um, 1.2)
    layout = Layout(3, False, False, True, True, ("defocus_sigma_um",), illumination=order)
    model = SceneModel(
        truth.image.shape, truth.microscope, truth.render, Camera(), placement, 1.2, layout
    )
    m = TRENCH.margin_um
    blocks = np.stack(
        [truth.cells.x_um + m, truth.cells.y_um + m, truth.cells.angle_rad, truth.cells.length_um],
        axis=1,
    )
    shared = [0.95, m, TRENCH.width_um, m, *TRUE_LIGHT, 0.15]
    return model, np.concatenate([blocks.ravel(), shared])


@pytest.mark.parametrize("k", [1, 3, 12, 13, 15, 16, 17])
def test_jacobian_columns_with_a_surface_match_full_renders(truth, k):
    """Cell columns (patches times the surface), the width, the surface's own exact
    columns and a kernel column against central differences of full renders."""
    model, x = _lit_model(truth)
    assert model.layout.global_names[4:9] == tuple(
        f"illumination.{t}" for t in ("x", "y", "x^2", "y^2", "xy")
    )
    a, scene, render = model.design(x)
    intensities = np.array([TRUTH.cell_intensity, TRUTH.media_intensity, TRUTH.device_intensity])
    free = np.zeros(x.size, bool)
    free[k] = True
    col = model.jacobian(x, a, intensities, scene, render, free)[:, 0].toarray().ravel()
    scale = model.layout.scales()[k]
    h = 0.3 * scale
    xp, xm = x.copy(), x.copy()
    xp[k] += h
    xm[k] -= h
    want = (model.design(xp)[0] @ intensities - model.design(xm)[0] @ intensities) / (2 * h)
    assert np.abs(want).max() > 1.0  # the parameter changes the image
    # forward differences of a cusp-y chord against central ones: a few % near edges
    assert np.abs(col / scale - want).max() < 0.08 * np.abs(want).max()


@pytest.mark.slow
def test_a_tilted_lamp_is_recovered_and_explains_the_image():
    """Rendered with the surface and camera noise, fitted with and without it."""
    truth = make_truth(seed=4)
    camera = Camera()
    lamp = illumination_stage(TRUE_LIGHT, 2)
    forward = ForwardModel(truth.microscope, TRUTH, camera, extra_stages=[lamp])
    image = forward.render(truth.scene, np.random.default_rng(4))
    common = {"camera": camera, "closed_end": "square", "moves": False, "irls_rounds": 2}
    lit = fit_scene(image, truth.microscope, TRUTH, illumination_order=2, **common)
    flat = fit_scene(image, truth.microscope, TRUTH, **common)
    assert lit.illumination_order == 2
    se = np.array([lit.standard_error(f"illumination.{t}") for t in illumination_terms(2)])
    assert np.all(se > 0)
    assert np.all(np.abs(lit.illumination - TRUE_LIGHT) < np.maximum(4 * se, 0.01))
    assert lit.objective_after < 1.15
    assert flat.objective_after > 1.5 * lit.objective_after  # 1.94 against 1.02
    assert len(lit.cells) == 3
    # the fit's stage renders its own synthetic image
    stage = lit.extra_stages()[0]
    clean = lit.synthetic - camera.baseline_adu
    unlit = clean / (1 + np.tensordot(lit.illumination, illumination_basis(image.shape, 2), 1))
    np.testing.assert_allclose(stage.apply(unlit.astype(np.float32), None), clean, rtol=1e-4)
    assert flat.extra_stages() == []


def test_flat_light_fitted_with_a_surface_stays_flat(truth):
    """No false surface: on an image rendered without one, the coefficients are
    within 4 standard errors of 0 and the fit is no better than the flat one's noise."""
    common = {"camera": truth.camera, "closed_end": "square", "moves": False, "irls_rounds": 2}
    lit = fit_scene(truth.image, truth.microscope, TRUTH, illumination_order=2, **common)
    se = np.array([lit.standard_error(f"illumination.{t}") for t in illumination_terms(2)])
    assert np.all(np.abs(lit.illumination) < 4 * se)
    assert np.all(se < 0.01)  # and the data do pin it down
    assert 0.9 < lit.objective_after < 1.1

