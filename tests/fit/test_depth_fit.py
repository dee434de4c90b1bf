"""The scene fit with the depth-resolved fluorescence image (eq. 16, ``depth_layers``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _fit_synthetic import make_fluorescence_field

from napari_symbac.fit import fit_scene
from napari_symbac.fit.engine import Layout, SceneModel, _add_patch
from napari_symbac.optics import ForwardModel
from napari_symbac.pipeline import stain_cells
from napari_symbac.settings import Camera

LAYERS = 5


def _model(truth, fraction: float, per_cell_brightness: bool = False, layers: int = LAYERS):
    render = dataclasses.replace(
        truth.render, envelope_stain_fraction=fraction, depth_layers=layers, focus_offset_um=0.2
    )
    optics = ("defocus_sigma_um", "focus_offset_um")
    layout = Layout(4, True, False, False, False, optics, per_cell_brightness)
    model = SceneModel(truth.image.shape, truth.microscope, render, Camera(), None, 1.2, layout)
    c = truth.cells
    columns = [c.x_um, c.y_um, c.angle_rad, c.length_um, np.array([0.0, 0.05, 0.0, 0.0])]
    if per_cell_brightness:
        columns.append(np.array([0.2, -0.1, 0.0, 0.3]))
    blocks = np.stack(columns, axis=1)
    return model, np.concatenate([blocks.ravel(), [0.9, 0.1, 0.2]])


@pytest.fixture(scope="module")
def field():
    return make_fluorescence_field()


@pytest.mark.parametrize(("fraction", "k"), [(0.6, 0), (0.6, 3), (0.6, 4), (0.6, 20), (0.0, 1)])
def test_cell_patch_in_depth_equals_the_difference_of_full_renders(field, fraction, k):
    """The Jacobian's patches image the stain slab by slab as the full render does: a
    cell's move (k < 20) or the shared width (k = 20) changes the cells column so."""
    model, x = _model(field, fraction)
    a, scene, render = model.design(x)
    flat = _model(field, fraction, layers=0)[0].design(x)[0]
    assert np.abs(a[:, 0] - flat[:, 0]).max() > 0.02 * np.abs(flat[:, 0]).max()
    x_new = x.copy()
    x_new[k] += 0.04
    kernels = model.forward.with_render(render).depth_kernels(1.2, scene.pixel_size_um)
    full = (model.design(x_new)[0][:, 0] - a[:, 0]).reshape(field.image.shape)
    local = np.zeros(full.size)
    for owner in [model.layout.owner(k)] if k < 20 else range(4):
        _add_patch(local, full.shape, *model.cell_delta(x, x_new, owner, scene, kernels), 1.0)
    assert np.abs(full).max() > 1e-3
    np.testing.assert_allclose(local.reshape(full.shape), full, atol=1e-4 * np.abs(full).max())


def test_brightness_column_in_depth_is_the_cells_own_stain(field):
    model, x = _model(field, 0.6, per_cell_brightness=True)
    a, scene, render = model.design(x)
    base = x.copy()
    base[5::6][:4] = 0.0  # no brightness offsets
    want = model.design(base)[0][:, 0].copy()
    kernels = model.forward.with_render(render).depth_kernels(1.2, scene.pixel_size_um)
    for i, db in enumerate((0.2, -0.1, 0.0, 0.3)):
        _add_patch(want, field.image.shape, *model.cell_delta(x, x, i, scene, kernels, True), db)
    np.testing.assert_allclose(a[:, 0], want, atol=1e-4 * np.abs(want).max())


def test_the_fit_model_is_the_forward_model(field):
    """The scene fit's design and the forward model render the same image (the cells'
    radii: the fitted width's half against the thickest drawn chord's, within 0.1 %)."""
    model, x = _model(field, 0.6)
    a, scene, render = model.design(x)
    intensities = np.array([1000.0, 20.0, 0.0])
    render = dataclasses.replace(render, cell_intensity=1000.0, media_intensity=20.0)
    forward = ForwardModel(field.microscope, render)
    image = forward.render_clean(stain_cells(scene, field.microscope, render))
    np.testing.assert_allclose(
        (a @ intensities).reshape(image.shape), image, atol=2e-3 * image.max()
    )


def test_the_kernel_column_in_depth_is_a_full_render(field):
    model, x = _model(field, 0.6)
    scene = model.design(x)[1]
    intensities = np.array([1000.0, 20.0, 0.0])
    xk = x.copy()
    xk[21] += 0.05  # defocus_sigma_um
    column = model.kernel_column(x, xk, scene, intensities)
    np.testing.assert_allclose(column, model.design(xk)[0] @ intensities, atol=1e-3)


def test_colicoords_ds2_cell_fits_its_rims_in_depth(real_data_dir):
    """ColiCoords ds2 field 00066, the 64 x 64 px around its top cell (see
    test_envelope_fit.py): imaged slab by slab (5 slabs, focal plane free), the envelope's
    fraction leaves its bound 1 and the reduced chi-square falls from 14.1 (the 2-D
    model) to 7.6."""
    import tifffile

    from napari_symbac.fit.camera_estimate import censored_pixels
    from napari_symbac.settings import Microscope, RenderSettings

    path = real_data_dir / "colicoords" / "test_data" / "ds2" / "fluorescence" / "00066.tif"
    crop = tifffile.imread(path).astype(float)[0:64, 224:288]
    microscope = Microscope(
        pixel_size_um=0.08,
        numerical_aperture=1.4,
        refractive_index=1.515,
        wavelength_um=0.52,
        modality="fluorescence",
    )
    render = RenderSettings(envelope_stain_fraction=1.0, depth_layers=5, focus_offset_um=0.2)
    fit = fit_scene(
        crop, microscope, render, None, geometry="open", valid=~censored_pixels(crop, None),
        fit_optics=("defocus_sigma_um", "envelope_stain_fraction", "focus_offset_um"),
    )  # fmt: skip
    assert len(fit.cells) == 1
    assert 0.6 < fit.render.envelope_stain_fraction < 0.95
    assert fit.objective_after < 9.0
    assert 1.0 < fit.cells.width_um[0] < 1.25
    assert 0.1 < abs(fit.render.focus_offset_um) < 0.4
