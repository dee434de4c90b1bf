"""The depth-resolved fluorescence image (eq. 16): the stain in slabs through the depth,
each through the PSF defocused by its distance from the focal plane."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from napari_symbac.fit.placement import draw_fitted
from napari_symbac.optics import ForwardModel
from napari_symbac.pipeline import apply_cell_brightness, stain_cells
from napari_symbac.scene import (
    depth_layer_centres_um,
    depth_stain,
    envelope_stain,
    stain_layers,
    stained_fraction,
)
from napari_symbac.settings import Microscope, RenderSettings
from napari_symbac.sim import FrameCells

MICROSCOPE = Microscope(
    pixel_size_um=0.08,
    numerical_aperture=1.4,
    refractive_index=1.515,
    wavelength_um=0.52,
    modality="fluorescence",
)
RENDER = RenderSettings(cell_intensity=1000.0, media_intensity=10.0, defocus_sigma_um=0.05)


@pytest.fixture(scope="module")
def scene():
    """One 3 x 1.1 um rod in the middle of a 64 x 64 px (5 x 5 um) open field."""
    cells = FrameCells(
        ids=np.array([1]),
        x_um=np.array([2.56]),
        y_um=np.array([2.56]),
        angle_rad=np.array([1.2]),
        length_um=np.array([3.0]),
        width_um=np.array([1.1]),
    )
    return draw_fitted(cells, None, (64, 64), MICROSCOPE, RENDER)


def _render(scene, render, microscope=MICROSCOPE, cache=True):
    return ForwardModel(microscope, render).render_clean(
        stain_cells(scene, microscope, render), cache=cache
    )


def _dip(image: np.ndarray) -> float:
    """1 - (centre line) / (mean of the two rims) along the row through the cell's middle,
    across its axis (the rod lies at 1.2 rad from vertical: nearly along the rows, so a
    column through the middle crosses it)."""
    column = image[:, 32].astype(np.float64)
    centre = column[32]
    return 1 - centre / (0.5 * (column[20:32].max() + column[33:45].max()))


@pytest.mark.parametrize("fraction", [0.0, 0.7, 1.0])
def test_the_slabs_add_up_to_the_2d_stain(scene, fraction):
    radius = np.where(scene.labels > 0, 0.55, 0.0)
    layers = stain_layers(scene.cells, radius, fraction, scene.depth_um, 7)
    flat = stained_fraction(scene.cells, radius, fraction, scene.depth_um)
    assert layers.shape == (7, *scene.shape)
    np.testing.assert_allclose(layers.sum(axis=0), flat, atol=2e-6)
    # the volume stain is symmetric about the mid-plane; the slabs beyond the cell
    # (|z| > 0.55 um of a 1.2 um depth in 7 slabs: none) hold nothing
    np.testing.assert_allclose(layers, layers[::-1], atol=1e-7)


def test_a_stain_in_the_envelope_sits_at_the_top_and_bottom_on_the_centre_line(scene):
    """On the centre line a volume stain fills every slab the cell crosses, an envelope
    stain only the top and bottom ones; at the rim both lie at mid-height."""
    radius = np.where(scene.labels > 0, 0.55, 0.0)
    centre = np.unravel_index(np.argmax(scene.cells), scene.shape)
    volume = stain_layers(scene.cells, radius, 0.0, scene.depth_um, 5)[(slice(None), *centre)]
    shell = stain_layers(scene.cells, radius, 1.0, scene.depth_um, 5)[(slice(None), *centre)]
    assert volume[2] == pytest.approx(volume[1], rel=1e-5)
    assert shell[2] == 0
    assert shell[0] > 0
    assert shell[4] == pytest.approx(shell[0], rel=1e-5)


def test_layer_centres():
    np.testing.assert_allclose(depth_layer_centres_um(1.2, 3), [-0.4, 0.0, 0.4])
    np.testing.assert_allclose(depth_layer_centres_um(1.0, 2), [-0.25, 0.25])
    with pytest.raises(ValueError, match="n_layers must be an integer >= 1"):
        depth_layer_centres_um(1.2, 0)


def test_off_is_bit_identical(scene):
    """depth_layers = 0 (the default) renders the 2-D model as before, cached or not; in
    phase contrast depth_layers changes nothing either."""
    render = dataclasses.replace(RENDER, envelope_stain_fraction=0.6)
    assert RenderSettings().depth_layers == 0
    model = ForwardModel(MICROSCOPE, render)
    for cache in (True, False):
        before = model.render_clean(envelope_stain(scene, 0.6), cache=cache)
        assert np.array_equal(_render(scene, render, cache=cache), before)
    assert "depth" not in [stage.name for stage in model.stages]
    phase = dataclasses.replace(MICROSCOPE, modality="phase")
    plain = RenderSettings(apodisation_sigma_um=1.0)
    layered = dataclasses.replace(plain, depth_layers=5)
    assert np.array_equal(_render(scene, layered, phase), _render(scene, plain, phase))


def test_one_slab_in_focus_is_the_2d_model(scene):
    """A single slab through the whole depth, in focus, is eq. OPL2's projection through
    the Airy PSF: the Debye PSF at z = 0 is the Airy pattern."""
    render = dataclasses.replace(RENDER, envelope_stain_fraction=0.6)
    flat = _render(scene, render)
    one = _render(scene, dataclasses.replace(render, depth_layers=1))
    np.testing.assert_allclose(one, flat, atol=2e-4 * flat.max())


def test_light_is_conserved_and_cached_and_composed_paths_agree(scene):
    render = dataclasses.replace(
        RENDER, envelope_stain_fraction=0.8, depth_layers=5, focus_offset_um=0.3
    )
    flat = _render(scene, dataclasses.replace(render, depth_layers=0))
    deep = _render(scene, render)
    assert deep.sum() == pytest.approx(flat.sum(), rel=2e-4)
    np.testing.assert_allclose(_render(scene, render, cache=False), deep, atol=1e-4 * deep.max())
    assert ForwardModel(MICROSCOPE, render).stages[0].name == "depth"


def test_the_focal_plane_above_or_below_the_mid_plane_gives_one_image(scene):
    up = dataclasses.replace(RENDER, depth_layers=5, focus_offset_um=0.25)
    down = dataclasses.replace(up, focus_offset_um=-0.25)
    np.testing.assert_allclose(_render(scene, up), _render(scene, down), atol=1e-3)


def test_depth_deepens_the_envelope_dip(scene):
    """The envelope's top and bottom (its projection's floor between the rims) lie out of
    focus and blur more than its in-focus sides: the dip between the rims deepens."""
    render = dataclasses.replace(RENDER, envelope_stain_fraction=1.0)
    flat = _dip(_render(scene, render))
    deep = _dip(_render(scene, dataclasses.replace(render, depth_layers=7)))
    assert flat > 0.05
    assert deep > flat + 0.04


def test_the_profile_survives_per_cell_brightness(scene):
    render = dataclasses.replace(RENDER, depth_layers=5, envelope_stain_fraction=0.5)
    stained = stain_cells(scene, MICROSCOPE, render)
    profile = stained.depth_profile
    assert profile.shape == (5, *scene.shape)
    np.testing.assert_allclose(profile.sum(axis=0), 1.0, atol=1e-5)
    bright = apply_cell_brightness(stained, 0.3, seed=1)
    assert bright.depth_profile is profile
    assert envelope_stain(scene, 0.5).depth_profile is None
    assert depth_stain(scene, 0.0, 3).cells is scene.cells


def test_settings_and_scenes_without_a_profile_are_refused(scene):
    for bad in (-1, 1.5, True, 33):
        with pytest.raises(ValueError, match="depth_layers must be an integer in"):
            RenderSettings(depth_layers=bad)
    model = ForwardModel(MICROSCOPE, dataclasses.replace(RENDER, depth_layers=3))
    with pytest.raises(ValueError, match="no depth profile of as many slabs"):
        model.render_clean(scene)
    with pytest.raises(ValueError, match="no depth profile of as many slabs"):
        model.render_clean(depth_stain(scene, 0.0, 5), cache=False)
    # no cells, no profile: the light (debris) at the cells' mid-plane
    empty = scene.replace_cells(np.zeros(scene.shape, np.float32))
    empty = dataclasses.replace(empty, labels=np.zeros(scene.shape, np.uint32))
    assert np.isfinite(model.render_clean(empty)).all()


def test_a_simulation_renders_in_depth_through_the_pipeline():
    """iter_render of a short fluorescence simulation with per-cell brightness and debris:
    each frame drawn with its depth profile, the light of the 2-D render kept."""
    from napari_symbac.pipeline import iter_render
    from napari_symbac.settings import PipelineSettings, SimulationSettings
    from napari_symbac.sim import simulate

    render = dataclasses.replace(
        RENDER, cell_brightness_cv=0.3, debris_density_per_100um2=2.0, noise_model="none"
    )
    flat = PipelineSettings(
        simulation=SimulationSettings(n_frames=3, seed=4),
        microscope=dataclasses.replace(MICROSCOPE, pixel_size_um=0.1),
        render=render,
    )
    deep = dataclasses.replace(
        flat, render=dataclasses.replace(render, depth_layers=5, focus_offset_um=0.2)
    )
    simulation = simulate(flat.simulation)
    for (a, labels_a, _), (b, labels_b, _) in zip(
        iter_render(simulation, flat), iter_render(simulation, deep)
    ):
        np.testing.assert_array_equal(labels_a, labels_b)
        assert not np.array_equal(a, b)
        assert float(b.sum()) == pytest.approx(float(a.sum()), rel=2e-3)
