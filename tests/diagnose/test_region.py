"""The window of a large frame that a diagnosis looks at."""

from __future__ import annotations

import numpy as np
import pytest

from napari_symbac.diagnose.region import (
    MAX_DIAGNOSIS_PIXELS,
    cells_region,
    default_region,
    parse_region,
    placement,
    simulated_shape,
)


def test_a_small_frame_is_diagnosed_whole():
    assert default_region((256, 46)) == (0, 256, 0, 46)
    assert default_region((256, 256)) == (0, 256, 0, 256)


def test_a_large_field_gives_its_centre_window():
    y0, y1, x0, x1 = default_region((512, 512))
    assert (y1 - y0, x1 - x0) == (256, 256)
    assert (y0, x0) == (128, 128)
    y0, y1, x0, x1 = default_region((1000, 400))  # aspect kept, within the budget
    assert (y1 - y0) * (x1 - x0) <= MAX_DIAGNOSIS_PIXELS
    assert (y1 - y0) / (x1 - x0) == pytest.approx(1000 / 400, rel=0.02)
    assert y0 + y1 == pytest.approx(1000, abs=1)
    assert x0 + x1 == pytest.approx(400, abs=1)


def test_a_long_trench_keeps_its_full_width():
    y0, y1, x0, x1 = default_region((4000, 46))
    assert (x0, x1) == (0, 46)
    assert (y1 - y0) * 46 <= MAX_DIAGNOSIS_PIXELS
    assert y1 - y0 == MAX_DIAGNOSIS_PIXELS // 46


def _frame(rows: int, cols: int) -> np.ndarray:
    return np.random.default_rng(0).normal(1000.0, 30.0, (rows, cols))


def test_parse_region():
    assert parse_region("full", _frame(512, 512)) == (0, 512, 0, 512)
    assert parse_region("10:138, 20:84", _frame(512, 512)) == (10, 138, 20, 84)
    # found as a user: a window partly outside the frame was "empty or outside" it
    with pytest.raises(ValueError, match=r"is not all inside the 64 x 32 frame \(rows 0:64"):
        parse_region("0:65,0:32", _frame(64, 32))
    with pytest.raises(ValueError, match=r"'32:16,0:32' is empty \(each end after its start"):
        parse_region("32:16,0:32", _frame(64, 32))
    with pytest.raises(ValueError, match="not of the form"):
        parse_region("0-64,0-32", _frame(64, 32))
    # the centre window, as by default (the Diagnose dock's default), of at most max_pixels
    assert parse_region(" Centre ", _frame(512, 512)) == default_region((512, 512))
    assert parse_region("center", _frame(512, 512)) == (128, 384, 128, 384)
    assert parse_region("centre", _frame(512, 512), max_pixels=64 * 64) == (224, 288, 224, 288)
    assert parse_region("centre", _frame(64, 32)) == (0, 64, 0, 32)
    # how each form places the window, in the CLI's note and the dock's status
    assert [placement(t) for t in (" Centre ", "CELLS", "full", "0:8,0:8")] == [
        "centre", "cells", "chosen", "chosen"
    ]
    # the errors name what the user gave it as, and every form accepted
    with pytest.raises(ValueError, match=r"^window 'middle' is not of the form") as err:
        parse_region("middle", _frame(64, 32), name="window")
    assert "give Y0:Y1,X0:X1 (rows and columns in pixels" in str(err.value)
    assert "full (the whole frame), cells (the window of at most 256 x 256 px" in str(err.value)
    assert "or centre (its centre window of that many)" in str(err.value)


def _holds(window: tuple[int, ...], box: tuple[int, ...]) -> bool:
    (y0, y1, x0, x1), (b0, b1, c0, c1) = window, box
    return y0 <= b0 and b1 <= y1 and x0 <= c0 and c1 <= x1


def test_the_cells_window_holds_the_most_whole_cells():
    """Found as a user: the centre 256 x 256 px of a ColiCoords 512 x 512 fluorescence
    field held none of its three cells whole; by default the window that holds the most
    is diagnosed, of the masks when given, in every frame of a series."""
    frame = _frame(512, 512)
    for y, x in [(40, 20), (60, 120), (300, 430)]:  # three cells, two near the corner
        frame[y : y + 12, x : x + 40] += 600
    y0, y1, x0, x1 = cells_region(frame)
    assert (y1 - y0, x1 - x0) == (256, 256)
    assert _holds((y0, y1, x0, x1), (40, 72, 20, 160))  # the two, whole
    assert parse_region("cells", frame) == (y0, y1, x0, x1)
    # by the masks when given: the cell far from the others
    masks = np.zeros(frame.shape, np.int32)
    masks[300:312, 430:470] = 1
    y0, y1, x0, x1 = cells_region(frame, masks)
    assert _holds((y0, y1, x0, x1), (300, 312, 430, 470))
    # a series: the window with cells in every frame
    other = _frame(512, 512)
    other[300:312, 430:470] += 600
    y0, y1, x0, x1 = cells_region(np.stack([frame, other]))
    assert _holds((y0, y1, x0, x1), (300, 312, 430, 470))
    # noise alone, or a frame no larger than the window: the centre one
    assert cells_region(_frame(512, 512)) == default_region((512, 512))
    assert cells_region(frame[:256, :256]) == (0, 256, 0, 256)


def test_a_trench_window_is_simulated_as_long_as_the_frame():
    # all the columns of a trench: the whole frame (a window may be too short to divide in)
    assert simulated_shape((80, 176, 0, 46), (256, 46), trench=True) == (256, 46)
    # a field, or a trench window that cuts its columns: the window
    assert simulated_shape((128, 384, 128, 384), (512, 512), trench=False) == (256, 256)
    assert simulated_shape((0, 96, 4, 40), (256, 46), trench=True) == (96, 36)
    assert simulated_shape((0, 256, 0, 46), (256, 46), trench=False) == (256, 46)


def test_the_cells_window_of_a_textured_bright_field_holds_its_cells(real_data_dir):
    """Found as a user: on ColiCoords' bright-field fields the pad's texture (a median
    departure of 3 s.d. of the noise) counted as cells, and the default window of 7 of
    the 10 fields held none of the masks' cells (00003: a window of texture beside its
    two cells, whose fit then kept 12 of 51 start cells and was refused as a colony).
    The texture raises the bar: the windows hold 18 of the masks' cells, none empty but
    one."""
    import tifffile
    from scipy import ndimage

    folder = real_data_dir / "colicoords" / "test_data" / "ds1"
    held = []
    for field in range(1, 11):
        image = tifffile.imread(folder / "brightfield" / f"{field:05d}.tif").astype(float)
        masks = tifffile.imread(folder / "binary" / f"{field:05d}_Probabilities_filtered.tif")
        y0, y1, x0, x1 = cells_region(image)
        boxes = ndimage.find_objects(ndimage.label(masks > 0)[0])
        held.append(
            sum(b[0].start >= y0 and b[0].stop <= y1 and b[1].start >= x0 and b[1].stop <= x1
                for b in boxes)
        )  # fmt: skip
    assert sum(held) >= 15, held
    assert sum(h == 0 for h in held) <= 1, held
