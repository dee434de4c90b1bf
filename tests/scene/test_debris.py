"""Debris: unlabelled out-of-focus particles on the medium (scene/_debris.py, issue 14)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import ndimage

from napari_symbac.pipeline import draw_frame, render_simulation
from napari_symbac.scene import add_debris
from napari_symbac.settings import (
    AgarPadGeometry,
    Microscope,
    PipelineSettings,
    RenderSettings,
    SimulationSettings,
)
from napari_symbac.sim import simulate


@pytest.fixture(scope="module")
def pad():
    return simulate(
        SimulationSettings(
            geometry="agar_pad", n_frames=24, agar_pad=AgarPadGeometry(20.0, 16.0), seed=7
        )
    )


def _fluorescence(simulation, **render) -> PipelineSettings:
    base = RenderSettings(
        psf_radius_px=20, cell_intensity=1000.0, media_intensity=50.0, noise_model="none"
    )
    return PipelineSettings(
        simulation=simulation.settings,
        microscope=Microscope(modality="fluorescence"),
        render=dataclasses.replace(base, **render),
    )


def test_default_has_no_debris_and_renders_bit_identically(pad):
    settings = _fluorescence(pad)
    assert settings.render.debris_density_per_100um2 == 0
    scene = draw_frame(pad, settings, 5)
    rng = np.random.default_rng(0)
    assert add_debris(scene, settings.render, rng) is scene
    assert rng.random() == np.random.default_rng(0).random()  # nothing drawn
    # explicitly off and never mentioned: the same bits (noise on: the stream is unchanged)
    noisy = dataclasses.replace(settings, render=RenderSettings(psf_radius_px=20))
    plain = render_simulation(pad, noisy)
    off = render_simulation(
        pad,
        dataclasses.replace(
            noisy, render=dataclasses.replace(noisy.render, debris_brightness=0.9)
        ),
    )
    np.testing.assert_array_equal(plain.images, off.images)
    np.testing.assert_array_equal(plain.labels, off.labels)


def test_debris_is_seen_but_never_labelled(pad):
    clean = _fluorescence(pad)
    dirty = _fluorescence(
        pad, debris_density_per_100um2=4.0, debris_brightness=0.3, debris_defocus_sigma_um=0.2
    )
    a = render_simulation(pad, clean)
    b = render_simulation(pad, dirty)
    np.testing.assert_array_equal(a.labels, b.labels)  # masks unchanged
    scene = draw_frame(pad, dirty, 10)
    plain = draw_frame(pad, clean, 10)
    np.testing.assert_array_equal(scene.labels, plain.labels)
    np.testing.assert_allclose(scene.cells + scene.media + scene.device, 1.0, atol=1e-5)
    moved = scene.cells - plain.cells
    assert moved.min() >= 0
    assert moved.max() > 0.1
    # particles lie on the medium: where a cell is labelled, nothing was added
    assert np.abs(moved[scene.labels > 0]).max() < 0.05
    # the image shows blobs outside the (dilated) masks, a few per 100 um^2
    image, labels = b.images[10].astype(float), b.labels[10]
    outside = ~ndimage.binary_dilation(labels > 0, iterations=4)
    blobs, _ = ndimage.label((image - a.images[10]) > 0.1 * (1000 - 50) * 0.3 * 0.5)
    found = np.unique(blobs[outside & (blobs > 0)]).size
    field_um2 = image.size * 0.065**2
    assert 0.5 * 4.0 * field_um2 / 100 < found < 2.0 * 4.0 * field_um2 / 100
    assert image[outside].max() > a.images[10][outside].max() + 50


def test_debris_same_seed_same_bits_static_and_other_seed_differs(pad):
    settings = _fluorescence(pad, debris_density_per_100um2=3.0)
    a, b = render_simulation(pad, settings), render_simulation(pad, settings)
    np.testing.assert_array_equal(a.images, b.images)
    first, last = draw_frame(pad, settings, 0), draw_frame(pad, settings, 23)
    plain0 = draw_frame(pad, _fluorescence(pad), 0)
    plain1 = draw_frame(pad, _fluorescence(pad), 23)
    free = (first.labels == 0) & (last.labels == 0)
    # the pad's particles do not move between frames (away from the growing cells)
    np.testing.assert_array_equal(
        (first.cells - plain0.cells)[free][:1000], (last.cells - plain1.cells)[free][:1000]
    )
    other = add_debris(plain0, settings.render, np.random.default_rng(99))
    assert not np.array_equal(other.cells, first.cells)


@pytest.mark.parametrize(
    "name", ["debris_density_per_100um2", "debris_brightness", "debris_defocus_sigma_um"]
)
def test_negative_debris_settings_are_refused(name):
    with pytest.raises(ValueError, match=name):
        RenderSettings(**{name: -1.0})
    with pytest.raises(ValueError, match="debris_diameter_um"):
        RenderSettings(debris_diameter_um=0.0)


def test_export_with_debris_series_static_labels_unchanged_default_untouched():
    from napari_symbac.export.dataset import ExportSettings, PipelineSource

    simulation = SimulationSettings(
        geometry="agar_pad", n_frames=6, agar_pad=AgarPadGeometry(10.0, 10.0), seed=2
    )

    def unit(**render):
        pipeline = PipelineSettings(
            simulation=simulation,
            microscope=Microscope(modality="fluorescence"),
            render=RenderSettings(
                psf_radius_px=20, cell_intensity=1000.0, media_intensity=50.0, **render
            ),
        )
        settings = ExportSettings(n_items=1, kind="timeseries", pipeline=pipeline, seed=4)
        return PipelineSource(settings).make_unit(0)

    plain = unit()
    # debris settings other than the density draw nothing: the same bits
    off = unit(debris_brightness=0.9, debris_diameter_um=2.0)
    for a, b in zip(plain, off):
        np.testing.assert_array_equal(a.image, b.image)
    dirty = unit(debris_density_per_100um2=5.0, debris_brightness=0.5)
    again = unit(debris_density_per_100um2=5.0, debris_brightness=0.5)
    for a, b, c in zip(plain, dirty, again):
        np.testing.assert_array_equal(a.labels, b.labels)  # never in the masks
        np.testing.assert_array_equal(b.image, c.image)  # same seed, same bits
    # the particles are where the pad is, on every frame: the excess over the clean
    # series is brightest at the same pixels in the first and the last frame
    excess = [b.image.astype(float) - a.image.astype(float) for a, b in zip(plain, dirty)]
    outside = (dirty[0].labels == 0) & (dirty[-1].labels == 0)
    first = ndimage.gaussian_filter(excess[0], 2) * outside
    last = ndimage.gaussian_filter(excess[-1], 2) * outside
    assert first.max() > 20
    assert np.unravel_index(first.argmax(), first.shape) == np.unravel_index(
        last.argmax(), last.shape
    )


def test_a_larger_particle_spreads_the_same_light(pad):
    """A particle of diameter ``d`` carries ``b (d_m / d)^2``: its material sums to that of
    a median one whatever its size (ColiCoords' field 3: blobs of 0.2-1.1 um all 80-180
    ADU above the pad; drawn at ``b`` each, 1-1.2 um particles came out as bright as the
    cells, unlabelled and cell-sized)."""
    settings = _fluorescence(
        pad,
        debris_density_per_100um2=1.0,
        debris_diameter_um=0.4,
        debris_diameter_cv=0.6,
        debris_brightness=0.2,
        debris_brightness_cv=0.0,
        debris_defocus_sigma_um=0.0,
    )
    scene = draw_frame(pad, settings, 0)
    plain = draw_frame(pad, _fluorescence(pad), 0)
    moved = np.asarray(scene.cells - plain.cells, np.float64)
    blobs, n = ndimage.label(moved > 0)
    assert n >= 5
    index = np.arange(1, n + 1)
    areas = ndimage.sum(np.ones_like(moved), blobs, index)
    light = ndimage.sum(moved, blobs, index) * scene.pixel_size_um**2
    edge = np.unique(np.concatenate([blobs[[0, -1]].ravel(), blobs[:, [0, -1]].ravel()]))
    whole = ~np.isin(index, edge)  # not cut by the field's edge
    assert areas[whole].max() > 4 * areas[whole].min()  # sizes differ ...
    # ... the light does not (each disk's edge is area-weighted: within a few per cent);
    # two particles that overlap make one blob of twice the light
    ratio = light[whole] / (0.2 * np.pi * 0.2**2)
    assert (np.round(ratio) >= 1).all()
    np.testing.assert_allclose(ratio, np.round(ratio), atol=0.1)
