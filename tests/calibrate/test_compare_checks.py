"""The comparison says per quantity whether the synthetic image matches the recording."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from napari_symbac.calibrate import compare_images
from napari_symbac.calibrate.compare import (
    GUI_WORDS,
    MEDIAN_TOLERANCE,
    SPECTRUM_FACTOR,
    Comparison,
    band_coefficients,
)


def _field(seed: int, *, cell_level: float = 1000.0, blur_px: float = 0.0):
    """A 128 x 128 field of 12 bright rods on a dark noisy background, and its masks."""
    rng = np.random.default_rng(seed)
    labels = np.zeros((128, 128), np.int32)
    y, x = np.mgrid[:128, :128]
    for k in range(12):
        cy, cx = 12 + 34 * (k // 4), 14 + 32 * (k % 4)
        labels[((y - cy) / 4.0) ** 2 + ((x - cx) / 10.0) ** 2 <= 1] = k + 1
    # a bright rim and a dimmer core, so that the 99th percentile lies on the rims and
    # the cells' normalised median follows the core's level
    rim = (labels > 0) & (ndimage.grey_erosion(labels, size=3) == 0)
    clean = np.where(labels > 0, cell_level, 200.0) + np.where(rim, 600.0, 0.0)
    if blur_px:
        clean = ndimage.gaussian_filter(clean, blur_px)
    return clean + rng.normal(0.0, 40.0, clean.shape), labels


def test_two_draws_of_the_same_field_match_in_every_comparison():
    real, masks = _field(0)
    synthetic, labels = _field(1)
    comparison = compare_images(real, masks, synthetic, labels)
    assert all(check.matched for check in comparison.checks())
    table = comparison.table()
    assert "MISMATCH" not in table
    assert "the synthetic data match the recording in 4 of 4 comparisons; mismatched: none" in (
        table
    )
    assert f"tolerance +-{MEDIAN_TOLERANCE:g}" in table
    assert "sampling noise" in table  # why that tolerance (said without project jargon)


def test_brighter_and_blurred_cells_are_flagged_with_what_to_do():
    real, masks = _field(0)
    synthetic, labels = _field(1, cell_level=1400.0, blur_px=1.5)
    comparison = compare_images(real, masks, synthetic, labels)
    by_name = {check.quantity: check for check in comparison.checks()}
    assert abs(comparison.cells[1] - comparison.cells[0]) > MEDIAN_TOLERANCE
    assert not by_name["cells median"].matched
    assert not by_name["power spectrum"].matched
    assert by_name["background median"].matched
    table = comparison.table()
    assert "- cells median: MISMATCH: synthetic" in table
    assert "- power spectrum: MISMATCH:" in table
    assert "- background median: MATCH:" in table
    verdict = comparison.verdict()
    assert verdict.startswith("the synthetic data match the recording in ")
    assert "mismatched: cells median" in verdict
    assert "power spectrum" in verdict.split("mismatched:")[1]
    assert "lacks fine detail" in verdict  # the blur: high bands lower
    assert "--masks" in verdict
    assert verdict in table  # the summary line ends the table
    # with the user's masks given, the advice does not ask for them
    given = compare_images(real, masks, synthetic, labels, masks_given=True).verdict()
    assert "mismatched: cells median" in given
    assert "--masks" not in given
    assert "look at the montage" in given
    # the dock's advice names its own controls, none of the command's options or files
    shown = compare_images(real, masks, synthetic, labels, words=GUI_WORDS).verdict()
    assert "choose the cell masks if you have them" in shown
    assert "the calibrated layer against the recording" in shown
    assert "--masks" not in shown
    assert "report.png" not in shown


def test_small_bands_get_the_tolerance_their_sampling_needs():
    counts = band_coefficients((48, 48), 16)
    assert 0 < counts[0] < counts[-1]  # annuli grow with the frequency
    assert (band_coefficients((128, 128), 16) > counts).all()  # and with the image
    flat = np.full(16, 1 / 16)
    comparison = Comparison(
        (0.5, 0.5), (0.1, 0.1), (0.05, 0.05), np.linspace(0, 0.5, 16), flat, flat,
        band_coefficients=counts,
    )
    factors = comparison.band_factors()
    assert factors.min() == pytest.approx(SPECTRUM_FACTOR)  # well-sampled bands
    assert factors[0] > 2 * SPECTRUM_FACTOR  # a band of a few coefficients


def test_several_synthetic_images_are_pooled():
    """The class medians over the pixels of all the synthetic images (each normalised on
    its own), the median noise and the mean spectrum; one image in a list is that image."""
    from napari_symbac.fit.masks import normalise_percentiles

    real, masks = _field(0)
    dim, dim_labels = _field(1, cell_level=600.0)
    bright, bright_labels = _field(2, cell_level=1400.0)
    alone = compare_images(real, masks, dim, dim_labels)
    listed = compare_images(real, masks, [dim], [dim_labels])
    assert listed.cells == alone.cells
    assert listed.background == alone.background
    np.testing.assert_array_equal(listed.power_synthetic, alone.power_synthetic)
    pooled = compare_images(real, masks, [dim, bright], [dim_labels, bright_labels])
    cells = np.concatenate(
        [
            normalise_percentiles(dim)[dim_labels > 0],
            normalise_percentiles(bright)[bright_labels > 0],
        ]
    )
    assert pooled.cells[1] == pytest.approx(np.median(cells))
    one, other = alone.cells[1], compare_images(real, masks, bright, bright_labels).cells[1]
    assert min(one, other) < pooled.cells[1] < max(one, other)
    assert pooled.cells[0] == alone.cells[0]  # the real image's own
    np.testing.assert_allclose(pooled.power_synthetic.sum(), 1.0)
    with pytest.raises(ValueError, match="as many synthetic images as label images"):
        compare_images(real, masks, [dim, bright], [dim_labels])


def test_a_saturated_synthetic_image_is_said_as_such():
    """Found as a user: bright field calibrated as phase drew items saturated at 65535,
    and the comparison said "the image is flat between its percentiles"."""
    real, masks = _field(0)
    synthetic, labels = _field(1)
    saturated = np.full(synthetic.shape, 65535, np.uint16)
    with pytest.raises(ValueError, match=r"synthetic item 1 is one grey level \(65535 ADU, "
                       r"the top of uint16: saturated\).*check the modality"):
        compare_images(real, masks, [synthetic, saturated], [labels, labels])
    with pytest.raises(ValueError, match=r"the recording is one grey level .*more cells"):
        compare_images(np.full(real.shape, 7.0), masks, synthetic, labels)
