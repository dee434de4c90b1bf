"""Several trenches side by side told apart from a dense colony (real images)."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile

from napari_symbac.fit.start import refuse_trenches_in_a_field

COLONY_PX_UM = 0.118  # the Omnipose colonies' cells ~1 um wide (they record no pixel size)


def _windows(image: np.ndarray, size: int):
    for y in range(0, image.shape[0] - size + 1, size // 2):
        for x in range(0, image.shape[1] - size + 1, size // 2):
            yield (y, x), image[y : y + size, x : x + size]


@pytest.mark.parametrize("name", ["Sample000033", "Sample000193", "Sample000252"])
def test_windows_of_a_dense_colony_are_not_trenches_side_by_side(real_data_dir, name):
    """Found as a user: windows of a colony fitted as an open field were refused as "N
    trenches side by side" (of 96 and 128 px windows of the three colonies, 60 of 583),
    naming a crop of each trench as the fix. Their columns' runs differ between the
    frame's thirds; none is refused so now."""
    image = iio.imread(real_data_dir / "omnipose" / f"{name}.png").astype(float)
    image = image[..., 0] if image.ndim == 3 else image  # grey saved as RGB(A), or grey
    refused = []
    for size in (96, 128):
        for corner, window in _windows(image, size):
            try:
                refuse_trenches_in_a_field(window, COLONY_PX_UM)
            except ValueError as err:
                refused.append((size, corner, str(err)))
    assert refused == []


@pytest.mark.parametrize("rows", [slice(0, 256), slice(0, 96), slice(100, 196), slice(150, 214)])
def test_four_real_trenches_side_by_side_are_refused_in_any_band_of_rows(real_data_dir, rows):
    """The SyMBac trench four times with PDMS between, whole or cut to a band of 64-96
    rows: still refused, naming each trench's columns and the crop to make."""
    trench = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    pdms = np.full((trench.shape[0], 30), int(np.median(trench[:, :5])), trench.dtype)
    four = np.hstack([trench, pdms, trench[:, ::-1], pdms, trench, pdms, trench])
    with pytest.raises(ValueError, match=r"holds 4 trenches side by side .*crop each trench"):
        refuse_trenches_in_a_field(four[rows], 0.065)
