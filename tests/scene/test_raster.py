"""The drawing's storage: media made on first read (Scene's pending images), and the
rows of cells and column spans that the compiled drawing sweeps (scene/_raster.py).
The values drawn are tested against the reference in test_draw_reference.py."""

from __future__ import annotations

import math
import pickle
from types import SimpleNamespace

import numpy as np
import pytest

from napari_symbac.scene import Field, Scene, draw_scene
from napari_symbac.scene._field import field_images
from napari_symbac.scene._raster import _row_span, _rows_of_cells, cell_boxes, chord
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


def test_rows_of_cells_list_every_box_covering_a_row_in_input_order():
    rng = np.random.default_rng(3)
    for n in (1, 5, 40):
        i0 = rng.integers(0, 500, n)
        boxes = np.stack([i0, i0 + rng.integers(0, 60, n), i0, i0 + 1], 1)  # some empty
        start, members = _rows_of_cells(boxes, 600)
        for i in range(600):
            expected = [k for k in range(n) if boxes[k, 0] <= i < boxes[k, 1]]
            assert members[start[i] : start[i + 1]].tolist() == expected


@pytest.mark.parametrize(
    "angle", [0.0, math.pi / 2, math.pi, -math.pi / 2, 1e-12, 1e-9, 2e-9, math.pi / 2 + 1e-10, 0.7]
)
@pytest.mark.parametrize("bend", [0.0, 0.3])
def test_row_spans_hold_every_pixel_with_a_chord(angle, bend):
    """The columns a row is drawn over hold every non-zero chord of the cell's box,
    whatever the axis (along the rows, across them, within 1e-9 of either), and are
    no more than the rectangle about the axis that holds the cell (``length x
    (width + 2 |a|)``) plus a margin of a few pixels."""
    px = 0.065 / 3
    shape = (400, 400)
    xc = (np.arange(shape[1]) + 0.5) * px
    yc = (np.arange(shape[0]) + 0.5) * px
    centre, length, width = (4.3, 4.4), 3.7, 0.9
    curvature = (bend, 1.0, 0.2) if bend else None
    args = (np.array([centre[0]]), np.array([centre[1]]), np.array([angle]))
    box = cell_boxes(*args, np.array([length]), np.array([width]), np.array([bend]), px, 0,
                     shape)[0]
    full = chord(xc, yc, centre, angle, length, width, curvature)
    assert np.count_nonzero(full[: box[0]]) == np.count_nonzero(full[box[1] :]) == 0
    r, half = width / 2, length / 2 - width / 2
    sin_a, cos_a = math.sin(angle), math.cos(angle)
    near = 1 + 2.0**-20
    drawn = 0
    for i in range(box[0], box[1]):
        lo, hi = _row_span(yc[i] - centre[1], sin_a, cos_a, (half + r) * near,
                           (r + bend) * near, centre[0], xc[0], px, box[2], box[3])
        assert box[2] <= lo <= hi <= box[3]
        inside = np.flatnonzero(full[i])
        if inside.size:
            assert lo <= inside[0]
            assert inside[-1] < hi
        drawn += hi - lo
    assert drawn >= np.count_nonzero(full) > 1000
    # the rectangle grown by 3 px a side when it lies along the pixel grid, else 6 px
    # of margin a row
    grown = (length / px + 6) * ((width + 2 * bend) / px + 6)
    assert drawn <= grown + 6 * (box[1] - box[0])
