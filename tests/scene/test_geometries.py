"""Scenes and renders of the 2-D geometries: chamber, agar pad, user's outline (section 13)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import ndimage

from napari_symbac.pipeline import draw_frame, iter_scenes, render_simulation
from napari_symbac.scene import Field, add_media_texture, draw_scene, field_of
from napari_symbac.settings import (
    AgarPadGeometry,
    Microscope,
    OutlineGeometry,
    PipelineSettings,
    RenderSettings,
    SimulationSettings,
    TrenchGeometry,
)
from napari_symbac.sim import simulate

BOX = ((0.0, 10.0), (0.0, 0.0), (6.0, 0.0), (6.0, 10.0))  # open at the bottom


@pytest.fixture(scope="module")
def pad():
    return simulate(
        SimulationSettings(
            geometry="agar_pad", n_frames=36, agar_pad=AgarPadGeometry(16.0, 14.0), seed=3
        )
    )


@pytest.fixture(scope="module")
def outline():
    return simulate(
        SimulationSettings(
            geometry="outline",
            n_frames=40,
            outline=OutlineGeometry(
                polylines_um=(BOX,), founders_um=((3.0, 2.0),), exit_margin_um=1.0
            ),
            seed=4,
        )
    )


@pytest.fixture(scope="module")
def chamber():
    return simulate(
        SimulationSettings(
            geometry="chamber",
            n_frames=30,
            n_founders=3,
            trench=TrenchGeometry(length_um=10.0, width_um=6.0),
            seed=5,
        )
    )


def _settings(simulation, **render) -> PipelineSettings:
    return PipelineSettings(
        simulation=simulation.settings,
        render=dataclasses.replace(RenderSettings(psf_radius_px=30), **render),
    )


def _check_masks(simulation, scene, index):
    frame = simulation.frames[index]
    labels = scene.camera_labels()
    assert set(np.unique(labels[labels > 0]).tolist()) == set(frame.ids.tolist())
    assert set(scene.cell_ids.tolist()) == set(frame.ids.tolist())
    # each cell's mask is where the cell is: its centroid is near the cell's centre
    field = field_of(simulation)
    ox, oy = (0.0, 0.0) if field is None else field.origin_um
    pixel = 0.065
    for cell_id, x, y in zip(frame.ids, frame.x_um, frame.y_um):
        rows, cols = np.nonzero(labels == cell_id)
        assert abs((cols.mean() + 0.5) * pixel + ox - x) < 0.5
        assert abs((rows.mean() + 0.5) * pixel + oy - y) < 0.5


def test_field_of_each_geometry(pad, outline, chamber):
    assert field_of(chamber) is None
    assert field_of(SimulationSettings()) is None
    f = field_of(pad)
    assert (f.width_um, f.height_um, f.origin_um, f.walls_um) == (16.0, 14.0, (0.0, 0.0), ())
    f = field_of(outline)
    assert f.origin_um == (-1.0, -1.0)
    assert (f.width_um, f.height_um) == (8.0, 12.0)
    assert f.walls_um == (BOX,)
    assert field_of(outline.settings) == f  # from the settings' polylines alike
    with pytest.raises(ValueError, match="width_um"):
        Field(0.0, 1.0)


def test_agar_pad_scene(pad):
    settings = _settings(pad)
    index = len(pad.frames) - 1
    scene = draw_frame(pad, settings, index)
    assert scene.camera_shape == (round(14 / 0.065), round(16 / 0.065))
    assert not scene.device.any()  # no device on an agar pad
    np.testing.assert_allclose(scene.cells + scene.media, 1.0, atol=1e-6)
    assert scene.depth_um == pad.settings.trench.depth_um
    _check_masks(pad, scene, index)
    opl = scene.optical_path_length()
    assert opl[scene.labels > 0].max() > opl[scene.labels == 0].max()
    assert len(pad.frames[index]) >= 20


def test_outline_scene(outline):
    settings = _settings(outline)
    index = len(outline.frames) - 1
    scene = draw_frame(outline, settings, index)
    assert scene.camera_shape == (round(12 / 0.065), round(8 / 0.065))
    _check_masks(outline, scene, index)
    np.testing.assert_allclose(scene.cells + scene.media + scene.device, 1.0, atol=1e-6)
    device = scene.interior(scene.device)
    px = scene.pixel_size_um
    # PDMS on the walls (left wall x = 0 -> column 1 um / px), nothing away from them
    wall_col = round(1.0 / px)
    assert device[round(5 / px) : round(10 / px), wall_col - 1 : wall_col + 1].max() == 1.0
    assert device[round(2 / px), round(1.0 / px) : round(7.0 / px)].max() == 1.0  # top wall
    assert device[:, round(2 / px) : round(6 / px)][round(2 / px) :].max() == 0.0
    assert device[round(11.5 / px) :].max() == 0.0  # open end: no wall
    # walls are the physics wall's thickness (0.1 um), about 5 render pixels
    assert device[round(6 / px)].sum() == pytest.approx(2 * 0.1 / px, rel=0.05)
    opl = scene.optical_path_length()
    media_only = (scene.labels == 0) & (scene.device == 0)
    assert opl[scene.labels > 0].max() > opl[media_only].max()
    assert opl[scene.device == 1].min() > opl[media_only].max()  # n_PDMS > n_media


def test_thick_walls_never_cover_cells():
    cells = dataclasses.make_dataclass(
        "C", ["ids", "x_um", "y_um", "angle_rad", "length_um", "width_um"]
    )
    one = cells(*(np.array([v]) for v in (1, 1.0, 3.0, 0.0, 3.0, 1.0)))
    field = Field(4.0, 6.0, walls_um=(((0.6, 0.0), (0.6, 6.0)),), wall_thickness_um=0.8)
    scene = draw_scene(one, TrenchGeometry(), Microscope(), RenderSettings(), field=field)
    assert scene.device.max() == 1.0
    np.testing.assert_allclose(scene.cells + scene.media + scene.device, 1.0, atol=1e-6)
    assert not np.any((scene.labels > 0) & (scene.device == 1.0))
    assert scene.camera_labels().max() == 1


def test_chamber_is_drawn_as_a_wide_trench(chamber):
    settings = _settings(chamber)
    index = len(chamber.frames) - 1
    scene = draw_frame(chamber, settings, index)
    direct = draw_scene(
        chamber.frames[index], chamber.settings.trench, settings.microscope, settings.render
    )
    np.testing.assert_array_equal(scene.cells, direct.cells)
    trench = chamber.settings.trench
    assert scene.camera_shape == (
        round((trench.length_um + trench.margin_um) / 0.065),
        round((trench.width_um + 2 * trench.margin_um) / 0.065),
    )
    labels = scene.camera_labels()
    assert set(np.unique(labels[labels > 0]).tolist()) == set(chamber.frames[index].ids.tolist())
    assert not np.any((scene.labels > 0) & (scene.device == 1.0))


def _near_and_far(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    cells = labels > 0
    near = ndimage.binary_dilation(cells, iterations=4) & ~ndimage.binary_dilation(
        cells, iterations=1
    )
    far = ~ndimage.binary_dilation(cells, iterations=25)
    return near, far


def test_rendered_agar_pad_phase_and_fluorescence(pad):
    phase = render_simulation(pad, _settings(pad, psf_offset=0.05))
    image, labels = phase.images[-1].astype(float), phase.labels[-1]
    near, far = _near_and_far(labels)
    assert far.sum() > 1000
    # dark cells on a bright background, with a bright halo around the colony
    assert image[labels > 0].mean() < 0.85 * image[far].mean()
    assert image[near].mean() > image[far].mean() + 10  # ADU; about 30 here

    settings = _settings(pad, noise_model="none", media_intensity=100.0, cell_intensity=3000.0)
    settings = dataclasses.replace(
        settings, microscope=dataclasses.replace(settings.microscope, modality="fluorescence")
    )
    fluo = render_simulation(pad, settings)
    image, labels = fluo.images[-1].astype(float), fluo.labels[-1]
    _near, far = _near_and_far(labels)
    assert image[labels > 0].mean() > 3 * image[far].mean()


def test_same_seed_same_bits_and_texture(pad):
    settings = _settings(pad, texture_amplitude=0.1)
    a = render_simulation(pad, settings)
    b = render_simulation(pad, settings)
    np.testing.assert_array_equal(a.images, b.images)
    np.testing.assert_array_equal(a.labels, b.labels)
    # the texture is static (same on every frame) and only changes the media
    scenes = list(iter_scenes(pad, settings))
    plain = draw_frame(pad, _settings(pad), 0)
    ratio = scenes[0].media[plain.media == 1] / plain.media[plain.media == 1]
    assert ratio.std() > 0.05
    np.testing.assert_array_equal(scenes[0].cells, plain.cells)
    both = (scenes[0].labels == 0) & (scenes[-1].labels == 0)
    np.testing.assert_array_equal(scenes[0].media[both], scenes[-1].media[both])
    np.testing.assert_array_equal(draw_frame(pad, settings, 0).media, scenes[0].media)
    # zero amplitude leaves the scene alone; another seed gives another texture
    assert add_media_texture(plain, 0.0, 1) is plain
    other = add_media_texture(plain, 0.1, pad.settings.seed + 1)
    assert not np.array_equal(other.media, scenes[0].media)


def test_a_measured_texture_has_the_scale_it_is_given(pad):
    """``texture_scale_um`` (calibrate's measured texture): a Perlin texture whose
    correlation length follows the lattice spacing given, unlike section 13.2.1's
    (0.1-0.5 of the field), the same for the same seed; a negative scale is refused."""
    from napari_symbac.calibrate.measure import measure_texture

    plain = draw_frame(pad, _settings(pad), 0)
    px = plain.pixel_size_um
    masks = np.zeros(plain.shape, np.int32)
    masks[:4, :4] = 1  # measure_texture wants a cell: one in a corner

    def correlation(scale_um: float) -> float:
        textured = add_media_texture(plain, 0.1, 5, scale_um)
        media = np.where(plain.media == 1, textured.media, 1.0)
        measured = measure_texture(media, masks, px, gap_um=0.1, trend_um=100 * scale_um)
        return measured.correlation_px * px

    fine, coarse = correlation(0.4), correlation(0.8)
    assert 0.2 < fine / 0.4 < 0.6  # about a quarter to half the lattice spacing
    assert coarse / fine == pytest.approx(2.0, rel=0.2)
    again = add_media_texture(plain, 0.1, 5, 0.4)
    np.testing.assert_array_equal(again.media, add_media_texture(plain, 0.1, 5, 0.4).media)
    with pytest.raises(ValueError, match="texture scale must be zero or positive"):
        add_media_texture(plain, 0.1, 5, -0.4)


@pytest.mark.parametrize("name", ["chamber", "pad", "outline"])
def test_render_simulation_every_geometry(name, request):
    simulation = request.getfixturevalue(name)
    settings = _settings(simulation)
    series = render_simulation(simulation, settings)
    assert series.images.shape == series.labels.shape
    assert series.images.shape[0] == len(simulation.frames)
    assert series.images.dtype == np.uint16
    final = series.labels[-1]
    assert set(np.unique(final[final > 0]).tolist()) == set(simulation.frames[-1].ids.tolist())


def test_dataset_export_draws_the_agar_pad():
    from napari_symbac.export.dataset import ExportSettings, PipelineSource

    simulation = SimulationSettings(
        geometry="agar_pad", n_frames=20, agar_pad=AgarPadGeometry(8.0, 8.0), seed=2
    )
    pipeline = PipelineSettings(
        simulation=simulation, render=RenderSettings(psf_radius_px=20, texture_amplitude=0.05)
    )
    settings = ExportSettings(n_items=1, first_frame=19, pipeline=pipeline)
    (item,) = PipelineSource(settings).make_unit(0)
    assert item.image.shape == item.labels.shape == (round(8 / 0.065),) * 2
    assert item.labels.max() > 0
    (again,) = PipelineSource(settings).make_unit(0)
    np.testing.assert_array_equal(item.image, again.image)
