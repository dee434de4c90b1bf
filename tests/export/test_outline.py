"""The masks' outline convention: offset of a user's outline, masks grown by it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import ndimage

from napari_symbac.export import ExportSettings
from napari_symbac.export.dataset import PipelineSource
from napari_symbac.export.outline import (
    border_ids,
    grow_masks,
    level_matched_growth_px,
    outline_level,
    outline_offset_px,
)
from napari_symbac.settings import PipelineSettings, SimulationSettings


def _disc(shape, centre, radius, value, out):
    rows, cols = np.indices(shape)
    out[(rows - centre[0]) ** 2 + (cols - centre[1]) ** 2 <= radius**2] = value
    return out


def test_offset_of_a_wider_outline_is_the_band_it_adds():
    model = np.zeros((80, 80), np.uint32)
    user = np.zeros((80, 80), np.int32)
    _disc(model.shape, (20, 20), 8, 1, model)
    _disc(model.shape, (55, 55), 10, 2, model)
    _disc(user.shape, (20, 20), 10, 5, user)  # 2 px outside
    _disc(user.shape, (55, 55), 10, 9, user)  # the same outline
    user[2:6, 70:76] = 3  # a cell the model did not fit: no pair
    offsets = outline_offset_px(user, model)
    assert offsets.size == 2
    assert offsets[0] == pytest.approx(2.0, abs=0.35)
    assert offsets[1] == pytest.approx(0.0, abs=0.05)
    assert outline_offset_px(user, np.zeros_like(model)).size == 0
    with pytest.raises(ValueError, match="one shape"):
        outline_offset_px(user[:10], model)


def _blurred_rods(sigma_px: float = 2.5):
    """Two bright rods (10 px wide) blurred by a Gaussian, on a level background; the
    third, cut by the image's border, is no whole cell."""
    labels = np.zeros((90, 120), np.int32)
    labels[20:30, 15:55] = 1
    labels[55:65, 40:95] = 2
    labels[80:90, 100:120] = 3
    image = 100.0 + ndimage.gaussian_filter(1000.0 * (labels > 0), sigma_px)
    return image, labels


def test_outline_level_is_the_edge_light_over_the_core_light():
    image, labels = _blurred_rods()
    assert border_ids(labels).tolist() == [3]
    levels = outline_level(image, labels)
    assert levels.size == 2  # the cut rod is left out
    # a blurred step: the edge pixels, half a pixel inside it, hold about half the core's
    # light (a bit more: 0.5 px in), far below 1 and above 0
    assert np.all((levels > 0.5) & (levels < 0.75))
    grown = outline_level(image, grow_masks(labels, 2.0))
    assert np.all(grown < levels)  # an outline further out lies lower in the light
    assert outline_level(image, np.zeros_like(labels)).size == 0  # no cell


def test_the_growth_that_reaches_a_level_is_found_back():
    image, labels = _blurred_rods()
    for growth in (1.0, 2.5):
        level = float(np.median(outline_level(image, grow_masks(labels, growth))))
        assert level_matched_growth_px(level, image, labels) == pytest.approx(growth, abs=0.3)
    own = float(np.median(outline_level(image, labels)))
    assert level_matched_growth_px(own + 0.1, image, labels) == 0.0  # never shrunk
    assert level_matched_growth_px(0.0, image, labels, max_px=3.0) == 3.0  # out of reach
    assert level_matched_growth_px(0.3, image, np.zeros_like(labels)) is None


def test_grown_masks_keep_cells_apart_and_grow_by_the_distance():
    labels = np.zeros((40, 60), np.uint32)
    labels[10:20, 10:30] = 1
    labels[10:20, 33:50] = 2  # 3 px gap
    grown = grow_masks(labels, 2.0)
    assert grown.dtype == labels.dtype
    assert (grown[labels > 0] == labels[labels > 0]).all()  # cells keep their pixels
    assert (grown[8:22, 20] == 1).all()  # 2 px above and below
    assert (grown[15, 8:30] == 1).all()  # and to the left
    assert grown[7, 20] == 0
    assert grown[8, 8] == 0  # Euclidean: the corner is rounded
    assert grown[15, 31] == 1  # the gap is shared, not overlapped
    assert grown[15, 32] == 2
    assert (grow_masks(labels, 0.0) == labels).all()
    with pytest.raises(ValueError, match="distance_px"):
        grow_masks(labels, -1.0)


def test_export_grows_its_masks_by_the_dilation_only():
    base = ExportSettings(
        n_items=2, seed=4, first_frame=5,
        pipeline=PipelineSettings(simulation=SimulationSettings(n_frames=10)),
    )
    grown = dataclasses.replace(base, mask_dilation_um=0.2)
    plain, wide = PipelineSource(base).make_unit(0)[0], PipelineSource(grown).make_unit(0)[0]
    assert np.array_equal(plain.image, wide.image)  # the image is not changed
    px = base.pipeline.microscope.pixel_size_um
    assert np.array_equal(wide.labels, grow_masks(plain.labels, 0.2 / px))
    assert (wide.labels > 0).sum() > (plain.labels > 0).sum()
    assert ((wide.semantic > 0) <= (wide.labels > 0)).all()
    assert (wide.semantic > 0).sum() > (plain.semantic > 0).sum()
    with pytest.raises(ValueError, match="mask_dilation_um"):
        dataclasses.replace(base, mask_dilation_um=-0.1)
