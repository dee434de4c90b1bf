"""The per-cell and per-texture-mode components of the design (issue 11): each is the
forward model's own image of that cell / that texture mode, so the effects that use
them reproduce a rendered change, not an approximation of it."""

from __future__ import annotations

import numpy as np
import pytest

from napari_symbac.diagnose.concealed import _cells, _draw, base_settings
from napari_symbac.diagnose.effects.background_texture import (
    BackgroundTexture,
    texture_basis,
    texture_modes,
)
from napari_symbac.diagnose.effects.background_texture import _modes as all_modes
from napari_symbac.diagnose.effects.cell_intensity_variability import CellIntensityVariability
from napari_symbac.diagnose.model import build_design
from napari_symbac.optics.forward import ForwardModel


def _trench(modality: str, seed: int):
    microscope, render, camera = base_settings(modality)
    cells, trench, field, shape = _cells("trench", np.random.default_rng(seed))
    scene = _draw(cells, trench, field, shape, microscope, render)
    model = ForwardModel(microscope, render, camera)
    design = build_design([scene], microscope, render, camera)
    parts = design.components * design.intensities[:, None, None, None]
    clean = model.render_clean(scene).astype(np.float64)[None]
    return scene, model, design, parts, clean


def test_per_cell_gains_reproduce_a_rendered_per_cell_brightness_in_phase():
    scene, model, design, parts, clean = _trench("phase", 3)
    geo = design.geometry
    gains = np.array([0.03, -0.02, 0.05, -0.04, 0.01, 0.02])[: len(geo.cell_ids)]
    gain_map = np.ones(scene.shape, np.float32)
    for i, g in zip(geo.cell_ids, gains):
        gain_map[scene.labels == i] = 1 + g
    truth = model.render_clean(scene.replace_cells(scene.cells * gain_map))[None] - clean
    effect = CellIntensityVariability(geo)
    got = effect.mean(gains, clean, parts, geo) - clean
    err = np.abs(got - truth).max() / np.abs(truth).max()
    assert err < 1e-3
    # the mask model it replaces (the cells' part on the pixels nearest each cell)
    # misses the phase halo beyond 4 px and the overlap of neighbours' images
    masks = np.stack([geo.nearest == i for i in geo.cell_ids]).astype(float)
    old = np.tensordot(gains, masks, axes=1) * parts[0]
    assert np.abs(old - truth).max() / np.abs(truth).max() > 10 * err


@pytest.mark.parametrize("modality", ["phase", "fluorescence"])
def test_texture_modes_are_the_media_times_the_mode_through_the_optics(modality):
    scene, model, design, parts, clean = _trench(modality, 5)
    geo = design.geometry
    modes = texture_modes(geo)
    assert geo.texture_components.shape == (len(modes), *geo.shape)
    # render the media times 1 + c B_k (the mode on the render grid, continued into
    # the border) and compare with the effect's change for theta = c e_k
    u, b = scene.upsample, scene.border_px
    rows, cols = geo.shape[1:]
    y = (np.arange(scene.shape[0]) - b + 0.5) / u / rows
    x = (np.arange(scene.shape[1]) - b + 0.5) / u / cols
    effect = BackgroundTexture(geo)
    for k in (0, len(modes) - 1):
        ky, kx = modes[k]
        mode = np.cos(np.pi * ky * y)[:, None] * np.cos(np.pi * kx * x)[None, :]
        textured = scene.replace_media((scene.media * (1 + 0.05 * mode)).astype(np.float32))
        truth = model.render_clean(textured)[None] - clean
        theta = np.zeros(effect.n_params())
        theta[k] = 0.05
        got = effect.mean(theta, clean, parts, geo) - clean
        assert np.abs(got - truth).max() < 2e-3 * np.abs(truth).max()
    # the camera-grid mode is the same mode: in open media (far from cells and walls)
    # the component is the mode times the media there, within the PSF's smoothing
    index = [all_modes(geo.shape[1:], geo.pixel_size_um).index(m) for m in modes]
    basis = texture_basis(geo.shape[1:], geo.pixel_size_um)[index]
    open_media = geo.media_fraction[0] > 0.999
    assert open_media.sum() > 100
    ratio = geo.texture_components[:, 0][:, open_media] / design.components[1, 0][open_media]
    np.testing.assert_allclose(ratio, basis[:, open_media], atol=0.1)


def test_the_bright_field_design_carries_the_lens_term_as_a_column():
    """Bright field: ``I_c C + I_m M + I_d D - kappa I_m L`` (docs/physics.md), the lens
    column ``L`` (cells through the lens kernel) after the intensities in ``beta``, its
    amplitude the base fit's ``kappa I_m``: the design's start is the rendered image."""
    from napari_symbac.diagnose.model import predict

    microscope, render, camera = base_settings("brightfield")
    cells, trench, field, shape = _cells("field", np.random.default_rng(3))
    scene = _draw(cells, trench, field, shape, microscope, render)
    design = build_design([scene], microscope, render, camera)
    assert design.n_linear == 4
    assert design.n_nuisance == 5  # and the defocus
    assert design.lens_amplitude == render.defocus_contrast_um2 * render.media_intensity
    clean = ForwardModel(microscope, render, camera).render_clean(scene).astype(np.float64)
    start = design.start()
    assert np.abs(predict(design, start, [])[0] - clean).max() < 1e-5 * np.ptp(clean)
    without = start.copy()
    without[3] = 0.0  # the cells' bright centres are the lens term's
    assert np.abs(predict(design, without, [])[0] - clean).max() > 0.3 * np.ptp(clean)
