"""The drawing's storage: media made on first read (Scene's pending images) and the
bands that the cells image is converted over (scene/_raster.py). The bent chord taken
near the axis only is tested against the reference in test_draw_reference.py."""

from __future__ import annotations

import math
import pickle
from types import SimpleNamespace

import numpy as np
import pytest

from napari_symbac.scene import Field, Scene, draw_scene
from napari_symbac.scene._field import field_images
from napari_symbac.scene._raster import _row_bands
from napari_symbac.settings import Microscope, RenderSettings, TrenchGeometry

MIC = Microscope()
RENDER = RenderSettings(upsample=3, psf_radius_px=12)


def _pad_scene(seed: int = 0) -> tuple[Scene, Field]:
    rng = np.random.default_rng(seed)
    n = 30
    width = rng.uniform(0.7, 1.2, n)
    cells = SimpleNamespace(
        ids=np.arange(1, n + 1),
        x_um=rng.uniform(0.0, 12.0, n),
        y_um=rng.uniform(0.0, 10.0, n),
        angle_rad=rng.uniform(0.0, math.pi, n),
        length_um=np.maximum(rng.uniform(1.5, 4.0, n), width),
        width_um=width,
    )
    field = Field(12.0, 10.0, walls_um=(((1.0, 1.0), (11.0, 9.0)),), wall_thickness_um=0.4)
    curvature = {3: (0.2, 1.0, 0.3), 7: (-0.25, 0.7, 0.0)}
    return draw_scene(cells, TrenchGeometry(), MIC, RENDER, curvature, field=field), field


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def test_media_is_made_on_first_read_as_open_minus_cells():
    scene, field = _pad_scene()
    assert "media" not in scene.__dict__  # not drawn with the scene
    open_frac, _ = field_images(field, scene.shape, scene.border_px, scene.pixel_size_um)
    media = scene.media
    assert _same_bits(media, open_frac - scene.cells)
    assert scene.media is media  # made once
    assert not media.flags.writeable
    assert media.min() >= 0
    np.testing.assert_allclose(scene.cells + scene.media + scene.device, 1.0, atol=1e-6)
    with pytest.raises(AttributeError, match="no attribute 'mediaa'"):
        _ = scene.mediaa


def test_pending_media_survives_replace_pickle_and_matches_an_eager_scene():
    scene, _ = _pad_scene(1)
    brighter = scene.replace_cells(scene.cells * np.float32(2.0))
    assert "media" not in brighter.__dict__
    restored = pickle.loads(pickle.dumps(scene))
    eager = Scene(
        cells=scene.cells,
        media=np.array(scene.media),
        device=scene.device,
        labels=scene.labels,
        border_px=scene.border_px,
        upsample=scene.upsample,
        camera_shape=scene.camera_shape,
        pixel_size_um=scene.pixel_size_um,
        depth_um=scene.depth_um,
        cell_ids=scene.cell_ids,
    )
    # The media of the copy is the original's (the cells' change does not move it).
    assert _same_bits(brighter.media, scene.media)
    assert _same_bits(restored.media, scene.media)
    assert restored.fingerprints == eager.fingerprints == scene.fingerprints
    assert brighter.fingerprints["media"] == scene.fingerprints["media"]
    assert brighter.fingerprints["cells"] != scene.fingerprints["cells"]
    textured = scene.replace_media(scene.media * np.float32(0.5))
    assert _same_bits(textured.media, scene.media * np.float32(0.5))


def test_row_bands_are_disjoint_and_cover_every_box():
    rng = np.random.default_rng(3)
    for n in (1, 5, 40):
        i0 = rng.integers(0, 500, n)
        j0 = rng.integers(0, 500, n)
        boxes = np.stack([i0, i0 + rng.integers(1, 60, n), j0, j0 + rng.integers(1, 60, n)], 1)
        bands = _row_bands(boxes)
        covered = np.zeros((600, 600), np.int64)
        for b0, b1, c0, c1 in bands:
            covered[b0:b1, c0:c1] += 1
        assert covered.max() == 1  # disjoint
        for b0, b1, c0, c1 in boxes.tolist():
            assert covered[b0:b1, c0:c1].min() == 1  # every box inside a band
        rows_with_boxes = np.zeros(600, bool)
        for b0, b1, _, _ in boxes.tolist():
            rows_with_boxes[b0:b1] = True
        assert np.array_equal(covered.any(axis=1), rows_with_boxes)  # no empty rows
