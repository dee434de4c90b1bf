"""Per-cell brightness variability (section 13.2.2): ``RenderSettings.cell_brightness_cv``."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from napari_symbac.optics import ForwardModel
from napari_symbac.pipeline import (
    apply_cell_brightness,
    cell_brightness_gains,
    draw_frame,
    iter_render,
    noise_rng,
)
from napari_symbac.scene import add_media_texture, draw_scene
from napari_symbac.settings import (
    Camera,
    Microscope,
    PipelineSettings,
    RenderSettings,
    TrenchGeometry,
    load_settings,
    save_settings,
)
from napari_symbac.sim import simulate

FLUO = Microscope(modality="fluorescence")
DARK = RenderSettings(
    psf_radius_px=20,
    cell_intensity=1000.0,
    media_intensity=0.0,
    device_intensity=0.0,
    noise_model="none",
)


@pytest.fixture
def grid_scene(cells_factory):
    """100 separated cells in a 10 x 10 grid of a wide chamber."""
    x, y = np.meshgrid(0.8 + 1.6 * np.arange(10), 1.75 + 3.5 * np.arange(10))
    cells = cells_factory(y.ravel(), x_um=x.ravel(), length_um=2.5, width_um=1.0)
    chamber = TrenchGeometry(length_um=35.0, width_um=16.0, depth_um=1.2, margin_um=1.0)
    return draw_scene(cells, chamber, FLUO, DARK)


@pytest.fixture(scope="module")
def small_sim():
    base = PipelineSettings()
    sim_settings = dataclasses.replace(base.simulation, n_frames=8, seed=4)
    return simulate(sim_settings), dataclasses.replace(base, simulation=sim_settings)


def _cell_means(image: np.ndarray, labels: np.ndarray, ids: np.ndarray) -> np.ndarray:
    return np.array([image[labels == i].mean() for i in ids])


def test_cv_of_cell_means_matches_setting(grid_scene):
    model = ForwardModel(FLUO, DARK, Camera())
    labels = grid_scene.camera_labels()
    ids = grid_scene.cell_ids
    plain = _cell_means(model.render_clean(grid_scene, cache=False), labels, ids)
    for cv in (0.15, 0.3, 0.5):
        varied = apply_cell_brightness(grid_scene, cv, seed=11)
        means = _cell_means(model.render_clean(varied, cache=False), labels, ids)
        # Each cell's mean scales by its gain (cells are far apart, so no blur mixes them).
        gains = cell_brightness_gains(ids, cv, 11)
        np.testing.assert_allclose(means / plain, gains, rtol=0.02)
        assert means.std() / means.mean() == pytest.approx(cv, abs=0.25 * cv)
    assert plain.std() / plain.mean() < 0.03  # pixel-grid alignment only


def test_gains_have_mean_one_and_the_cv():
    gains = cell_brightness_gains(np.arange(1, 20001), 0.4, 7)
    assert gains.mean() == pytest.approx(1.0, abs=0.01)
    assert gains.std() / gains.mean() == pytest.approx(0.4, abs=0.01)
    assert np.all(gains > 0)
    np.testing.assert_array_equal(cell_brightness_gains([5, 9], 0.0, 7), [1.0, 1.0])
    with pytest.raises(ValueError, match="cv must be zero or positive"):
        cell_brightness_gains([1], -0.1, 7)


def test_max_gain_truncates_the_gamma_and_keeps_the_gains_below_it():
    ids = np.arange(1, 5001)
    free = cell_brightness_gains(ids, 0.99, 7)
    bounded = cell_brightness_gains(ids, 0.99, 7, max_gain=1.6)
    assert free.max() > 3.0  # the tail the bound cuts
    assert bounded.max() <= 1.6
    below = free <= 1.6
    np.testing.assert_array_equal(bounded[below], free[below])
    assert np.all(bounded[~below] != free[~below])
    np.testing.assert_array_equal(bounded, cell_brightness_gains(ids, 0.99, 7, 1.6))
    for bad in (0.5, -1.0, np.nan, np.inf):
        with pytest.raises(ValueError, match="max_gain must be 0"):
            cell_brightness_gains(ids[:2], 0.5, 7, bad)
        with pytest.raises(ValueError, match="cell_brightness_max_gain must be 0"):
            RenderSettings(cell_brightness_max_gain=bad)


def test_every_drawn_cell_keeps_within_the_max_gain(small_sim):
    simulation, settings = small_sim
    bounded = dataclasses.replace(
        settings,
        microscope=FLUO,
        render=dataclasses.replace(
            settings.render, cell_brightness_cv=1.0, cell_brightness_max_gain=1.2
        ),
    )
    free = dataclasses.replace(
        bounded, render=dataclasses.replace(bounded.render, cell_brightness_max_gain=0.0)
    )
    plain = dataclasses.replace(bounded, render=settings.render)
    ratios = {}
    for index in range(len(simulation.frames)):
        scenes = [draw_frame(simulation, s, index) for s in (bounded, free, plain)]
        for cell_id in scenes[2].cell_ids:
            inside = (scenes[2].labels == cell_id) & (scenes[2].cells > 0.05)
            if inside.any():
                base = scenes[2].cells[inside][0]
                ratios[int(cell_id)] = [float(s.cells[inside][0] / base) for s in scenes[:2]]
    got = np.array(list(ratios.values()))
    assert got[:, 0].max() <= 1.2 + 1e-6
    assert got[:, 1].max() > 1.2  # without the bound some cell is brighter


def test_a_cell_keeps_its_gain_whatever_the_other_cells():
    all_ids = cell_brightness_gains([3, 8, 12], 0.3, 5)
    alone = cell_brightness_gains([8], 0.3, 5)
    assert all_ids[1] == alone[0]
    assert not np.array_equal(cell_brightness_gains([8], 0.3, 6), alone)


def test_zero_cv_renders_exactly_as_before(small_sim):
    simulation, settings = small_sim
    assert settings.render.cell_brightness_cv == 0.0
    got = list(iter_render(simulation, settings))
    # The path before the setting existed: draw, texture, render, Scene's own masks.
    rng = noise_rng(settings)
    model = ForwardModel(settings.microscope, settings.render, settings.camera)
    for index, (image, labels, semantic) in enumerate(got):
        scene = add_media_texture(
            draw_scene(
                simulation.frames[index],
                settings.simulation.trench,
                settings.microscope,
                settings.render,
            ),
            settings.render.texture_amplitude,
            simulation.settings.seed,
        )
        assert apply_cell_brightness(scene, 0.0, 1) is scene
        np.testing.assert_array_equal(image, model.render(scene, rng, cache=False))
        np.testing.assert_array_equal(labels, scene.camera_labels())
        np.testing.assert_array_equal(semantic, scene.semantic_mask())


def test_same_seed_same_bits_and_cells_keep_their_gain(small_sim):
    simulation, settings = small_sim
    varied = dataclasses.replace(
        settings,
        microscope=FLUO,
        render=dataclasses.replace(settings.render, cell_brightness_cv=0.4),
    )
    first = [frame[0] for frame in iter_render(simulation, varied)]
    again = [frame[0] for frame in iter_render(simulation, varied)]
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    plain_settings = dataclasses.replace(varied, render=settings.render)
    seen: dict[int, float] = {}
    for index in range(len(simulation.frames)):
        scene = draw_frame(simulation, varied, index)
        plain = draw_frame(simulation, plain_settings, index)
        for cell_id in scene.cell_ids:
            inside = (scene.labels == cell_id) & (plain.cells > 0.05)
            if not inside.any():
                continue
            ratio = scene.cells[inside] / plain.cells[inside]
            np.testing.assert_allclose(ratio, ratio[0], rtol=1e-6)
            seen.setdefault(int(cell_id), float(ratio[0]))
            assert ratio[0] == pytest.approx(seen[int(cell_id)], rel=1e-6)
            expected = cell_brightness_gains([cell_id], 0.4, simulation.settings.seed)[0]
            assert ratio[0] == pytest.approx(expected, rel=1e-6)
    assert len(seen) >= 2


def test_setting_validates_and_round_trips(tmp_path):
    with pytest.raises(ValueError, match="cell_brightness_cv must be zero or positive"):
        RenderSettings(cell_brightness_cv=-0.2)
    settings = PipelineSettings(
        microscope=FLUO, render=dataclasses.replace(DARK, cell_brightness_cv=0.35)
    )
    for suffix in (".yaml", ".json"):
        path = save_settings(settings, tmp_path / f"settings{suffix}")
        loaded = load_settings(path, PipelineSettings)
        assert loaded == settings
        assert loaded.render.cell_brightness_cv == 0.35


def _reference_masks(scene) -> tuple[np.ndarray, np.ndarray]:
    """Camera masks the plain way: a majority vote over every block, then the neighbours."""
    b, u = scene.border_px, scene.upsample
    rows, cols = scene.camera_shape
    inner = scene.labels[b : b + rows * u, b : b + cols * u]
    blocks = inner.reshape(rows, u, cols, u).transpose(0, 2, 1, 3).reshape(rows, cols, u * u)
    counts = np.stack([(blocks == blocks[..., k : k + 1]).sum(-1) for k in range(u * u)], -1)
    best = np.argmax(counts, axis=-1)  # the first (row-major) of equal counts
    labels = np.take_along_axis(blocks, best[..., None], axis=-1)[..., 0].astype(np.uint32)
    wide = labels.astype(np.int64)
    padded = np.pad(wide, 1)
    semantic = np.zeros(labels.shape, np.uint8)
    for i in range(rows):
        for j in range(cols):
            own = wide[i, j]
            around = padded[i : i + 3, j : j + 3]
            semantic[i, j] = own > 0 and not np.any((around > 0) & (around < own))
    return labels, semantic


def test_camera_masks_equal_reference(cells_factory):
    trench = TrenchGeometry(length_um=15.0, width_um=1.4, margin_um=0.8)
    rng = np.random.default_rng(1)
    for upsample in (1, 2, 3, 4):
        render = RenderSettings(upsample=upsample, psf_radius_px=10)
        for _ in range(10):
            n = 10
            cells = cells_factory(
                rng.uniform(0, 15, n),
                x_um=rng.uniform(0.3, 1.1, n),
                angle_rad=rng.normal(0, 0.5, n),
                length_um=rng.uniform(1.0, 4.0, n),
                width_um=0.9,
                ids=rng.permutation(np.arange(1, 40))[:n],
            )
            scene = draw_scene(cells, trench, Microscope(), render)
            labels, semantic = scene.camera_labels(), scene.semantic_mask()
            assert labels.dtype == np.uint32
            assert semantic.dtype == np.uint8
            ref_labels, ref_semantic = _reference_masks(scene)
            np.testing.assert_array_equal(labels, ref_labels)
            np.testing.assert_array_equal(semantic, ref_semantic)
            # Computed once per scene; every call returns a new, writable array.
            again = scene.camera_labels()
            assert again is not labels
            assert again.flags.writeable
            np.testing.assert_array_equal(again, labels)
            # A scene with new cells or media has the same labels, so the same masks.
            brighter = scene.replace_cells(scene.cells * 2)
            np.testing.assert_array_equal(brighter.camera_labels(), ref_labels)
            np.testing.assert_array_equal(brighter.semantic_mask(), ref_semantic)


def test_a_dim_cell_fades_to_the_medium_never_below_it(grid_scene):
    """A gain ``g < 1`` gives the cell's ``1 - g`` share back to the medium: over a bright
    medium a cell of gain near 0 is as bright as the medium, not a dark rod (ColiCoords
    ds3: two unlabelled rods darker than the background in a calibrated item)."""
    model = ForwardModel(FLUO, dataclasses.replace(DARK, media_intensity=300.0), Camera())
    scene = apply_cell_brightness(grid_scene, 1.5, 11)
    ids = scene.cell_ids
    gains = cell_brightness_gains(ids, 1.5, 11)
    assert gains.min() < 0.05  # some cells nearly unstained
    labels = scene.camera_labels()
    means = _cell_means(model.render_clean(scene, cache=False), labels, ids)
    # the same field with every cell's place filled by medium
    empty = grid_scene.replace_cells(np.zeros_like(grid_scene.cells)).replace_media(
        grid_scene.cells + grid_scene.media
    )
    medium = _cell_means(model.render_clean(empty, cache=False), labels, ids)
    assert (means > medium - 1.0).all()
    # a cell's brightness above the medium is its gain's share of a full one's, for a
    # brighter cell too (its extra thickness displaces medium: eq. 3 adds g (I_c - I_m),
    # not g I_c)
    assert gains.max() > 2.0
    ratio = (means - medium) / gains
    np.testing.assert_allclose(ratio, np.median(ratio), rtol=0.05)
