"""A scene drawn from a real image's instance masks."""

from __future__ import annotations

import numpy as np
import pytest

from napari_symbac.scene import cell_thickness_from_masks, scene_from_masks
from napari_symbac.settings import Microscope, RenderSettings


def _pair() -> np.ndarray:
    labels = np.zeros((30, 40), np.int64)
    labels[5:16, 5:35] = 1  # 11 px wide
    labels[16:27, 5:35] = 2  # touching it along its length
    return labels


def test_thickness_is_a_cylinder_chord_per_region():
    thickness = cell_thickness_from_masks(_pair())
    assert thickness[10, 20] == pytest.approx(1.0)  # centre line of cell 1
    assert thickness[21, 20] == pytest.approx(1.0)  # centre line of cell 2
    assert thickness[0, 0] == 0.0
    # the outermost pixel: half a pixel from the edge of a radius-5.5 px cylinder
    expected = np.sqrt(1 - (1 - 0.5 / 5.5) ** 2)
    assert thickness[15, 20] == pytest.approx(expected, rel=1e-5)
    assert thickness[16, 20] == pytest.approx(expected, rel=1e-5)  # the seam stays thin
    assert thickness.max() <= 1.0


def test_scene_from_masks_shapes_and_materials():
    microscope = Microscope(pixel_size_um=0.1)
    render = RenderSettings(upsample=2, psf_radius_px=8)
    scene = scene_from_masks(_pair(), microscope, render)
    assert scene.camera_shape == (30, 40)
    assert scene.shape == (30 * 2 + 16, 40 * 2 + 16)
    assert scene.pixel_size_um == pytest.approx(0.05)
    np.testing.assert_allclose(scene.cells + scene.media, 1.0)
    assert not scene.device.any()
    np.testing.assert_array_equal(scene.camera_labels(), _pair())
    np.testing.assert_array_equal(scene.cell_ids, [1, 2])


def test_bad_masks_are_rejected():
    with pytest.raises(ValueError, match="integer instance mask"):
        cell_thickness_from_masks(np.zeros((4, 4)))
    with pytest.raises(ValueError, match="non-negative"):
        cell_thickness_from_masks(-np.ones((4, 4), np.int64))
    with pytest.raises(ValueError, match="depth_um"):
        scene_from_masks(_pair(), Microscope(), RenderSettings(), depth_um=0.0)
