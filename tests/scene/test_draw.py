"""Scene drawing: geometry (eq. OPL1-3), curvature (eq. 1), masks (eq. 4-5)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from skimage.measure import label as cc_label

from napari_symbac.scene import draw_scene, kymograph
from napari_symbac.settings import Microscope, RenderSettings, TrenchGeometry

MIC = Microscope()
RS = RenderSettings(psf_radius_px=12)
TRENCH = TrenchGeometry(length_um=15.84, width_um=1.4, depth_um=1.2, margin_um=0.8)


def coords(scene):
    """Physical (x, y) of render-pixel centres, origin at the field of view's corner."""
    px, b = scene.pixel_size_um, scene.border_px
    y = (np.arange(scene.shape[0]) - b + 0.5) * px
    x = (np.arange(scene.shape[1]) - b + 0.5) * px
    return x, y


def test_field_of_view_shape(cells_factory):
    scene = draw_scene(cells_factory([3.0]), TRENCH, MIC, RS)
    assert scene.camera_shape == (256, 46)
    assert scene.shape == (256 * 3 + 24, 46 * 3 + 24)
    default = draw_scene(cells_factory([3.0]), TrenchGeometry(), MIC, RenderSettings())
    assert default.camera_shape == (round(16.8 / 0.065), round(3.0 / 0.065))
    assert default.border_px == 50
    for name in ("cells", "media", "device"):
        assert getattr(scene, name).dtype == np.float32
    assert scene.labels.dtype == np.uint32


def test_settings_of_the_wrong_kind_are_named(cells_factory):
    """Found as an API user: ``draw_scene(cells, trench, microscope, None)`` failed with
    "'NoneType' object has no attribute 'upsample'"."""
    cells = cells_factory([3.0])
    with pytest.raises(TypeError, match=r"draw_scene\(render=...\) needs RenderSettings"):
        draw_scene(cells, TRENCH, MIC, None)
    with pytest.raises(TypeError, match=r"needs Microscope, got RenderSettings"):
        draw_scene(cells, TRENCH, RS, MIC)
    with pytest.raises(TypeError, match=r"draw_scene\(trench=...\) needs TrenchGeometry"):
        draw_scene(cells, {"width_um": 1.5}, MIC, RS)


def test_materials_partition_depth(cells_factory):
    scene = draw_scene(cells_factory([3.0, 7.0]), TRENCH, MIC, RS)
    total = scene.cells + scene.media + scene.device
    np.testing.assert_allclose(total, 1.0, atol=1e-6)
    x, y = coords(scene)
    # Device well outside the trench, media in the empty lower part of the trench.
    col_dev = np.argmin(abs(x - 0.3))
    row_empty = np.argmin(abs(y - 12.0))
    col_mid = np.argmin(abs(x - (0.8 + 0.7)))
    assert scene.device[row_empty, col_dev] == 1.0
    assert scene.media[row_empty, col_mid] == 1.0
    # The closed end (top margin) is device, the open end continues into the border.
    assert scene.device[np.argmin(abs(y - 0.3)), col_mid] == 1.0
    assert scene.media[-1, col_mid] == 1.0


def test_projected_thickness_matches_chord(cells_factory):
    """cells * depth == 2 sqrt(r^2 - d^2), d = distance to the axis segment."""
    r, length, angle = 0.45, 3.0, 0.3
    cx, cy = 1.5, 5.0
    scene = draw_scene(
        cells_factory([cy], x_um=cx, angle_rad=angle, length_um=length, width_um=2 * r),
        TrenchGeometry(length_um=15.84, width_um=3.0, depth_um=1.2, margin_um=0.8),
        MIC,
        RS,
    )
    x, y = coords(scene)
    xx, yy = np.meshgrid(x - 0.8, y - 0.8)
    # Independent distance to the segment via projection onto its end points.
    half = length / 2 - r
    ax, ay = math.sin(angle), math.cos(angle)
    p0 = np.array([cx - half * ax, cy - half * ay])
    p1 = np.array([cx + half * ax, cy + half * ay])
    seg = p1 - p0
    tpar = np.clip(((xx - p0[0]) * seg[0] + (yy - p0[1]) * seg[1]) / (seg @ seg), 0, 1)
    d = np.hypot(xx - (p0[0] + tpar * seg[0]), yy - (p0[1] + tpar * seg[1]))
    expected = 2 * np.sqrt(np.maximum(r**2 - d**2, 0))
    np.testing.assert_allclose(scene.cells * 1.2, expected, atol=2e-5)
    # The centre-line of a full-depth cell would be exactly 1.
    assert scene.cells.max() == pytest.approx(2 * r / 1.2, abs=1e-3)


def test_thick_cells_are_capped_at_full_depth(cells_factory):
    trench = TrenchGeometry(length_um=15.84, width_um=1.4, depth_um=0.8, margin_um=0.8)
    scene = draw_scene(cells_factory([3.0], width_um=1.2), trench, MIC, RS)
    assert scene.cells.max() == 1.0
    assert scene.media.min() >= 0


def test_instance_and_semantic_masks(cells_factory):
    # Three touching cells (pole to pole), huge ids that would wrap in uint16.
    ids = [70_000, 2**31 + 5, 4_000_000_000]
    scene = draw_scene(cells_factory([2.0, 5.0, 8.0], ids=ids), TRENCH, MIC, RS)
    lab = scene.camera_labels()
    assert lab.dtype == np.uint32
    assert lab.shape == scene.camera_shape
    assert set(np.unique(lab)) == {0, *ids}
    # Area close to the analytic spherocylinder area (pi r^2 + 2 r (L - 2r)).
    area_um2 = math.pi * 0.25 + 1.0 * 2.0
    for cell_id in ids:
        assert (lab == cell_id).sum() * 0.065**2 == pytest.approx(area_um2, rel=0.05)
    sem = scene.semantic_mask()
    assert sem.dtype == np.uint8
    assert set(np.unique(sem)) == {0, 1}
    assert cc_label(sem, connectivity=2).max() == 3
    # The instance mask of touching cells has no gap: the cells are 8-connected.
    assert cc_label(lab > 0, connectivity=2).max() == 1


def test_curvature_rolls_image_and_mask(cells_factory):
    a = 0.25
    straight = draw_scene(cells_factory([5.0], length_um=4.0), TRENCH, MIC, RS)
    bent = draw_scene(
        cells_factory([5.0], length_um=4.0), TRENCH, MIC, RS, curvature={1: (a, 1.0, 0.0)}
    )
    x, _ = coords(straight)
    row = straight.border_px + round(5.8 / straight.pixel_size_um)  # the middle row (margin 0.8)

    def centroid(img, r):
        w = img[r]
        return (w * x).sum() / w.sum()

    shift_img = centroid(bent.cells, row) - centroid(straight.cells, row)
    shift_mask = centroid((bent.labels > 0).astype(float), row) - centroid(
        (straight.labels > 0).astype(float), row
    )
    assert shift_img == pytest.approx(a, abs=0.02)
    assert shift_mask == pytest.approx(a, abs=0.03)
    # Near the poles sin(l pi) ~ 0: no shift.
    top = straight.border_px + round((5.8 - 1.9) / straight.pixel_size_um)
    assert abs(centroid(bent.cells, top) - centroid(straight.cells, top)) < 0.05
    # Cells stay inside the trench even when bent into the wall.
    into_wall = draw_scene(cells_factory([5.0], length_um=4.0), TRENCH, MIC, RS, {1: (0.4, 1, 0)})
    assert into_wall.media.min() >= 0
    assert (into_wall.cells[into_wall.device == 1] == 0).all()


def test_optical_path_length(cells_factory):
    scene = draw_scene(cells_factory([3.0]), TRENCH, MIC, RS)
    n_c, n_m, n_p, s_p = 1.39, 1.333, 1.41, 5.0
    opl = scene.optical_path_length(n_c, n_m, n_p, s_p)
    x, y = coords(scene)
    dev = opl[np.argmin(abs(y - 8)), np.argmin(abs(x - 0.2))]
    empty = opl[np.argmin(abs(y - 12)), np.argmin(abs(x - 1.5))]
    centre = opl[np.argmin(abs(y - 3.8)), np.argmin(abs(x - 1.5))]
    assert dev == pytest.approx(n_p * s_p, rel=1e-6)  # OPL1
    assert empty == pytest.approx(n_p * (s_p - 1.2) + n_m * 1.2, rel=1e-6)  # OPL3
    chord = scene.cells[np.argmin(abs(y - 3.8)), np.argmin(abs(x - 1.5))] * 1.2
    opl2 = n_c * chord + n_m * (1.2 - chord) + n_p * (s_p - 1.2)
    assert centre == pytest.approx(opl2, rel=1e-6)  # OPL2
    assert chord == pytest.approx(1.0, abs=0.01)
    with pytest.raises(ValueError, match="pdms_thickness"):
        scene.optical_path_length(pdms_thickness_um=0.5)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"x_um": np.nan}, "NaN"),
        ({"length_um": 0.5}, "shorter"),
        ({"ids": [0]}, "ids"),
        ({"ids": [2**33]}, "uint32"),
    ],
)
def test_bad_cells_raise(cells_factory, kwargs, match):
    with pytest.raises(ValueError, match=match):
        draw_scene(cells_factory([3.0], **kwargs), TRENCH, MIC, RS)


def test_duplicate_ids_and_bad_curvature_raise(cells_factory):
    with pytest.raises(ValueError, match="unique"):
        draw_scene(cells_factory([3.0, 6.0], ids=[4, 4]), TRENCH, MIC, RS)
    with pytest.raises(ValueError, match="curvature"):
        draw_scene(cells_factory([3.0]), TRENCH, MIC, RS, curvature={1: (0.1, 0.0, 0.0)})


def test_trench_origin_and_camera_shape_place_the_trench(cells_factory):
    cells = cells_factory([3.0, 7.0])
    bend = {1: (0.1, 1.0, 0.0)}
    scene = draw_scene(cells, TRENCH, MIC, RS, bend)
    m = TRENCH.margin_um
    same = draw_scene(
        cells, TRENCH, MIC, RS, bend, trench_origin_um=(m, m), camera_shape=scene.camera_shape
    )
    for name in ("cells", "media", "device", "labels"):
        np.testing.assert_array_equal(getattr(same, name), getattr(scene, name))
    # Move the trench (and its cells) by whole render pixels in a smaller field of view.
    px = scene.pixel_size_um
    di, dj = 6, -9
    moved = draw_scene(
        cells,
        TRENCH,
        MIC,
        RS,
        bend,
        trench_origin_um=(m + dj * px, m + di * px),
        camera_shape=(200, 40),
    )
    assert moved.camera_shape == (200, 40)
    assert moved.shape == (200 * 3 + 24, 40 * 3 + 24)
    rows, cols = 500, 100  # well inside both fields of view
    for name in ("cells", "media", "device", "labels"):
        new = getattr(moved, name)[di + 20 : di + 20 + rows, 20 : 20 + cols]
        old = getattr(scene, name)[20 : 20 + rows, 20 - dj : 20 - dj + cols]
        np.testing.assert_allclose(new, old, atol=1e-5, err_msg=name)
    with pytest.raises(ValueError, match="finite"):
        draw_scene(cells, TRENCH, MIC, RS, trench_origin_um=(math.nan, 0.0))
    with pytest.raises(ValueError, match="smaller than one camera pixel"):
        draw_scene(cells, TRENCH, MIC, RS, camera_shape=(0, 10))


def test_a_top_margin_of_its_own_moves_the_closed_end_down(cells_factory):
    """``top_margin_um`` (a fitted trench's closed end) adds device rows above the
    trench, and is the same as placing the trench there by hand."""
    import dataclasses

    cells = cells_factory([3.0, 7.0])
    top = dataclasses.replace(TRENCH, top_margin_um=2.0)
    assert TRENCH.shown_top_um == TRENCH.margin_um
    assert top.shown_top_um == 2.0
    scene = draw_scene(cells, top, MIC, RS)
    plain = draw_scene(cells, TRENCH, MIC, RS)
    extra_rows = round((TRENCH.length_um + 2.0) / MIC.pixel_size_um) - plain.camera_shape[0]
    assert scene.camera_shape == (plain.camera_shape[0] + extra_rows, plain.camera_shape[1])
    placed = draw_scene(
        cells,
        TRENCH,
        MIC,
        RS,
        trench_origin_um=(TRENCH.margin_um, 2.0),
        camera_shape=scene.camera_shape,
    )
    for name in ("cells", "media", "device", "labels"):
        np.testing.assert_array_equal(getattr(scene, name), getattr(placed, name))
    # the closed end: device down to 2 um in the trench's middle column
    column = scene.device[:, scene.shape[1] // 2]
    first_media = np.argmax(column < 0.5) - RS.psf_radius_px
    assert first_media * scene.pixel_size_um == pytest.approx(2.0, abs=scene.pixel_size_um)
    with pytest.raises(ValueError, match="top_margin_um"):
        TrenchGeometry(top_margin_um=-1.0)


def test_empty_frame_and_scene_is_read_only(cells_factory):
    scene = draw_scene(cells_factory([]), TRENCH, MIC, RS)
    assert scene.labels.max() == 0
    assert scene.semantic_mask().max() == 0
    with pytest.raises(ValueError, match="read-only"):
        scene.cells[0, 0] = 1.0


def test_kymograph():
    frames = np.arange(3 * 4 * 2).reshape(3, 4, 2)
    k = kymograph(frames, gap_px=1, fill=-1)
    assert k.shape == (4, 3 * 2 + 2)
    np.testing.assert_array_equal(k[:, 3:5], frames[1])
    assert (k[:, 2] == -1).all()
    with pytest.raises(ValueError, match="stack"):
        kymograph(frames[0])
