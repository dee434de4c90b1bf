"""The synthetic agar-pad sample (issue 6) opens in napari."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("napari", reason="the [gui] extra (napari + Qt) is not installed")


def test_agar_pad_sample_opens(make_napari_viewer):
    viewer = make_napari_viewer()
    viewer.open_sample("napari-symbac", "agar_pad")
    image = viewer.layers["synthetic agar pad"]
    labels = viewer.layers["synthetic agar pad labels"]
    assert image.data.ndim == 3
    assert image.data.shape == labels.data.shape
    assert image.data.dtype == np.uint16
    assert image.data.shape[1:] == (385, 385)  # 25 um / 0.065 um
    np.testing.assert_allclose(image.scale[1:], 0.065)
    for frame, mask in zip(image.data, labels.data):
        assert len(np.unique(mask)) - 1 >= 50  # a colony, not a few cells
        # dark cells on a bright agar background (phase contrast)
        assert frame[mask > 0].mean() < frame[mask == 0].mean()
