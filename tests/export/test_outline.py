"""The masks' outline convention: offset of a user's outline, masks grown by it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from napari_symbac.export import ExportSettings
from napari_symbac.export.dataset import PipelineSource
from napari_symbac.export.outline import grow_masks, outline_offset_px
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
