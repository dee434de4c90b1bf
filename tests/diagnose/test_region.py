"""The window of a large frame that a diagnosis looks at."""

from __future__ import annotations

import pytest

from napari_symbac.diagnose.region import (
    MAX_DIAGNOSIS_PIXELS,
    default_region,
    parse_region,
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


def test_parse_region():
    assert parse_region("full", (512, 512)) == (0, 512, 0, 512)
    assert parse_region("10:138, 20:84", (512, 512)) == (10, 138, 20, 84)
    # found as a user: a window partly outside the frame was "empty or outside" it
    with pytest.raises(ValueError, match=r"is not all inside the 64 x 32 frame \(rows 0:64"):
        parse_region("0:65,0:32", (64, 32))
    with pytest.raises(ValueError, match=r"'32:16,0:32' is empty \(each end after its start"):
        parse_region("32:16,0:32", (64, 32))
    with pytest.raises(ValueError, match="not of the form"):
        parse_region("0-64,0-32", (64, 32))
    # the centre window, as by default (the Diagnose dock's default), of at most max_pixels
    assert parse_region(" Centre ", (512, 512)) == default_region((512, 512))
    assert parse_region("center", (512, 512)) == (128, 384, 128, 384)
    assert parse_region("centre", (512, 512), max_pixels=64 * 64) == (224, 288, 224, 288)
    assert parse_region("centre", (64, 32)) == (0, 64, 0, 32)
    # the errors name what the user gave it as, and every form accepted
    with pytest.raises(ValueError, match=r"^window 'middle' is not of the form") as err:
        parse_region("middle", (64, 32), name="window")
    assert "give Y0:Y1,X0:X1 (rows and columns in pixels" in str(err.value)
    assert "full (the whole frame) or centre (its centre window of at most 256" in str(err.value)


def test_a_trench_window_is_simulated_as_long_as_the_frame():
    # all the columns of a trench: the whole frame (a window may be too short to divide in)
    assert simulated_shape((80, 176, 0, 46), (256, 46), trench=True) == (256, 46)
    # a field, or a trench window that cuts its columns: the window
    assert simulated_shape((128, 384, 128, 384), (512, 512), trench=False) == (256, 256)
    assert simulated_shape((0, 96, 4, 40), (256, 46), trench=True) == (96, 36)
    assert simulated_shape((0, 256, 0, 46), (256, 46), trench=False) == (256, 46)
