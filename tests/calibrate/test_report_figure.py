"""calibrate's report.png (:func:`napari_symbac.calibrate.montage`) says which side is
real and which synthetic, which row has the outlines, and the grey scales in ADU."""

from __future__ import annotations

import numpy as np

from napari_symbac.calibrate import montage
from napari_symbac.figure_layout import map_scale


def _grey_bars(picture: np.ndarray, min_length: int) -> int:
    """Columns going steadily from white down to black over ``min_length`` rows or more."""
    count = 0
    for x in range(picture.shape[1]):
        column = picture[:, x].astype(int)
        steady = np.all(np.diff(column, axis=0) <= 0, axis=1)
        start = 0
        for i in range(len(steady) + 1):
            if i < len(steady) and steady[i]:
                continue
            ends = column[start].min() >= 245 and column[i].max() <= 10
            if ends and i - start + 1 >= min_length:
                count += 1
                break
            start = i + 1
    return count


def test_report_figure_is_labelled_and_large_enough():
    rng = np.random.default_rng(0)
    real = 100 + 50 * rng.random((64, 64))
    synthetic = 120 + 40 * rng.random((70, 64))
    masks = np.zeros((64, 64), np.int32)
    masks[20:40, 10:30] = 1
    labels = np.zeros((70, 64), np.int32)
    labels[30:50, 20:40] = 1
    picture = montage(real, synthetic, masks, labels)
    scale = map_scale((64, 64))
    assert 64 * scale >= 400
    assert picture.dtype == np.uint8
    assert picture.ndim == 3
    # two rows of two enlarged panels, under a heading and titles
    assert picture.shape[0] >= 2 * 64 * scale + 100
    assert picture.shape[1] >= 2 * 64 * scale
    strip = picture[:40].min(axis=-1)
    assert (strip >= 250).mean() > 0.8  # heading text on white
    assert (strip < 80).any()
    # a grey colour bar beside each panel (two columns of bars: at least 4 bars)
    assert _grey_bars(picture, int(0.95 * 64 * scale)) >= 4
    # outlines in green in the lower row only
    green = (picture == (0, 255, 0)).all(axis=-1)
    rows = np.flatnonzero(green.any(axis=1))
    assert rows.size
    assert rows.min() > picture.shape[0] // 2


def test_report_figure_without_masks_has_one_row():
    rng = np.random.default_rng(0)
    picture = montage(rng.random((64, 64)), rng.random((64, 64)))
    scale = map_scale((64, 64))
    assert 64 * scale <= picture.shape[0] < 2 * 64 * scale
    assert not (picture == (0, 255, 0)).all(axis=-1).any()


def test_a_trench_is_drawn_in_one_row_tall_enough_to_read():
    rng = np.random.default_rng(0)
    masks = np.zeros((256, 46), np.int32)
    masks[20:80, 10:36] = 1
    picture = montage(rng.random((256, 46)), rng.random((256, 46)), masks, masks)
    scale = map_scale((256, 46))
    assert 256 * scale >= 400
    assert 256 * scale <= picture.shape[0] < 2 * 256 * scale
    assert picture.shape[1] >= 4 * 46 * scale
    assert _grey_bars(picture, int(0.95 * 256 * scale)) >= 4


def test_the_real_outlines_are_titled_as_the_fitted_cells_when_no_masks_were_given():
    """Found as a user: calibrate without --masks titled its panel "real image with its
    masks outlined", of the fit's cells. The title differs; the pictures do not."""
    rng = np.random.default_rng(1)
    real, synthetic = rng.random((64, 64)), rng.random((64, 64))
    masks = np.zeros((64, 64), np.int32)
    masks[20:40, 10:30] = 1
    given = montage(real, synthetic, masks, masks)
    fitted = montage(real, synthetic, masks, masks, real_masks_fitted=True)
    assert given.shape == fitted.shape
    differ = np.flatnonzero((given != fitted).any(axis=(1, 2)))
    assert differ.size  # the lower row's title
    green = np.flatnonzero((fitted == (0, 255, 0)).all(axis=-1).any(axis=1))
    assert differ.max() < green.min()  # only above the outlined panels: the title
