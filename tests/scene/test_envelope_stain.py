"""A stain in the cell envelope: the shell's projection (eq. OPL2 extended)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from napari_symbac.optics import ForwardModel
from napari_symbac.pipeline import stain_cells
from napari_symbac.scene import (
    ENVELOPE_THICKNESS_UM,
    Field,
    draw_scene,
    envelope_stain,
    envelope_weight,
    shell_chord_um,
)
from napari_symbac.settings import Microscope, RenderSettings, TrenchGeometry
from napari_symbac.sim import FrameCells

R_UM, T_UM = 0.45, ENVELOPE_THICKNESS_UM
FLUO = Microscope(pixel_size_um=0.08, modality="fluorescence")
RENDER = RenderSettings(
    cell_intensity=2000.0, media_intensity=100.0, device_intensity=0.0, psf_radius_px=30
)


def _chord(d: np.ndarray, r: float) -> np.ndarray:
    return 2 * np.sqrt(np.maximum(r * r - d * d, 0.0))


def _scene(angle_rad: float = 0.0, length_um: float = 3.0):
    cells = FrameCells(
        ids=np.array([1, 2]),
        x_um=np.array([2.0, 5.0]),
        y_um=np.array([2.5, 2.5]),
        angle_rad=np.array([angle_rad, 0.4]),
        length_um=np.array([length_um, 2.2]),
        width_um=np.array([2 * R_UM, 0.8]),
    )
    return draw_scene(cells, TrenchGeometry(), FLUO, RENDER, field=Field(7.2, 5.2))


def test_the_shell_is_the_difference_of_two_chords_and_integrates_to_the_annulus():
    d = np.linspace(-0.6, 0.6, 240_001)
    shell = shell_chord_um(_chord(d, R_UM), R_UM, T_UM)
    np.testing.assert_allclose(shell, _chord(d, R_UM) - _chord(d, R_UM - T_UM), atol=1e-12)
    step = d[1] - d[0]
    annulus = np.pi * (R_UM**2 - (R_UM - T_UM) ** 2)  # the shell's cross-section
    assert shell.sum() * step == pytest.approx(annulus, rel=1e-4)
    # weighted, it carries the stain of the filled cross-section (pi r^2)
    weighted = envelope_weight(R_UM, T_UM) * shell.sum() * step
    assert weighted == pytest.approx(np.pi * R_UM**2, rel=1e-4)
    assert _chord(d, R_UM).sum() * step == pytest.approx(np.pi * R_UM**2, rel=1e-4)


def test_the_shell_is_limb_brightened_and_finite():
    centre = shell_chord_um(np.array([2 * R_UM]), R_UM, T_UM)[0]
    rim = shell_chord_um(_chord(np.array([R_UM - T_UM]), R_UM), R_UM, T_UM)[0]
    assert centre == pytest.approx(2 * T_UM)
    assert rim == pytest.approx(2 * np.sqrt(T_UM * (2 * R_UM - T_UM)))
    assert rim > 4 * centre


def test_point_samples_on_the_render_grid_sum_to_the_annulus_on_average():
    """The docstring's claim: about 2 % per row (s.d.), unbiased, at 80 nm / 3."""
    rng = np.random.default_rng(0)
    px = 0.08 / 3
    annulus = np.pi * T_UM * (2 * R_UM - T_UM)
    errors = []
    for _ in range(400):
        d = (np.arange(-30, 30) + rng.random()) * px
        errors.append(shell_chord_um(_chord(d, R_UM), R_UM, T_UM).sum() * px / annulus - 1)
    assert abs(np.mean(errors)) < 0.005
    assert np.std(errors) < 0.03


def test_fraction_zero_is_the_scene_itself_and_renders_bit_for_bit():
    scene = _scene()
    assert envelope_stain(scene, 0.0) is scene
    assert stain_cells(scene, FLUO, RENDER) is scene  # the default fraction is 0
    phase = Microscope(pixel_size_um=0.08)
    assert stain_cells(scene, phase, dataclasses.replace(RENDER, envelope_stain_fraction=1.0)) is (
        scene
    )
    model = ForwardModel(FLUO, RENDER)
    want = model.render(_scene(), np.random.default_rng(1))
    got = model.render(stain_cells(scene, FLUO, RENDER), np.random.default_rng(1))
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("angle_rad", [0.0, 0.7])
def test_an_envelope_stain_is_brighter_at_the_rim_and_keeps_the_light_per_length(angle_rad):
    scene = _scene(angle_rad, length_um=5.0)
    shell = envelope_stain(scene, 1.0)
    assert np.array_equal(shell.labels, scene.labels)
    assert np.array_equal(shell.media, scene.media)  # the cells fill the same volume
    # across the middle of the first cell (upright at angle 0: along the image's
    # columns), rim brighter than centre line
    model = ForwardModel(FLUO, dataclasses.replace(RENDER, media_intensity=0.0))
    volume_image, shell_image = model.render_clean(scene), model.render_clean(shell)
    row = round(2.5 / 0.08)
    centre = round(2.0 / 0.08)
    if angle_rad == 0.0:
        v, s = volume_image[row], shell_image[row]
        assert v[centre] > v[centre + 5]  # volume: brightest on the centre line
        assert s[centre + 4] > 1.2 * s[centre]  # envelope: brightest near the rim
    # the cylinder's light per unit length is kept: a band across its middle, 2 um long,
    # within the render grid's point sampling (about 2 % s.d. per row; a cell along the
    # rows has every row sampled alike, so its error does not average out)
    yy, xx = np.mgrid[0 : scene.shape[0], 0 : scene.shape[1]]
    px = scene.pixel_size_um
    b = scene.border_px
    x_um, y_um = (xx - b + 0.5) * px - 2.0, (yy - b + 0.5) * px - 2.5
    along = y_um * np.cos(angle_rad) + x_um * np.sin(angle_rad)
    band = (np.abs(along) < 1.0) & (scene.labels == 1)
    assert shell.cells[band].sum() == pytest.approx(scene.cells[band].sum(), rel=0.03)
    # the poles' shell carries more (3 t / r of the sphere against 2 t / r): the whole
    # cell a few per cent brighter, never less
    whole = scene.labels == 1
    ratio = shell.cells[whole].sum() / scene.cells[whole].sum()
    assert 1.0 < ratio < 1.15


def test_half_the_stain_in_the_envelope_is_the_mean_of_the_two():
    scene = _scene(0.3)
    half = envelope_stain(scene, 0.5).cells
    mean = (scene.cells + envelope_stain(scene, 1.0).cells) / 2
    np.testing.assert_allclose(half, mean, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("fraction", [-0.1, 1.2, float("nan")])
def test_a_fraction_outside_zero_to_one_is_refused(fraction):
    with pytest.raises(ValueError, match=r"fraction must be in \[0, 1\]"):
        envelope_stain(_scene(), fraction)
