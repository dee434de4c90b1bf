"""Joint fit of a time series: optics shared by the frames, cells per frame."""

from __future__ import annotations

import numpy as np
import pytest
from _fit_synthetic import FLUO_TRUTH, make_fluorescence_series

from napari_symbac.fit import fit_series
from napari_symbac.settings import RenderSettings


@pytest.fixture(scope="module")
def series():
    truth = make_fluorescence_series(3)
    stack = np.stack([frame.image for frame in truth])
    start = RenderSettings(defocus_sigma_um=0.0)
    return truth, fit_series(stack, truth[0].microscope, start, None, geometry="open")


def test_shared_defocus_is_recovered_with_a_smaller_error_than_frame_by_frame(series):
    _truth, fit = series
    assert fit.shared_names == ("defocus_sigma_um",)
    value, se = fit.shared()["defocus_sigma_um"]
    assert abs(value - FLUO_TRUTH.defocus_sigma_um) < 3 * se
    # three frames measure it: about 1/sqrt(3) of one frame's error
    assert se < 0.75 * fit.frame_standard_errors.min()
    assert fit.frame_values.shape == fit.frame_standard_errors.shape == (3, 1)
    # every frame's fit carries the one shared value
    for frame in fit.frames:
        assert frame.render.defocus_sigma_um == pytest.approx(value, rel=1e-9)
    assert not fit.warnings


def test_each_frame_keeps_its_own_cells(series):
    truth, fit = series
    assert [len(frame.cells) for frame in fit.frames] == [len(t.cells) for t in truth]
    for frame, want in zip(fit.frames, truth):
        got = np.sort(frame.cells.length_um)
        np.testing.assert_allclose(got, np.sort(want.cells.length_um), atol=0.06)
        assert frame.objective_after == pytest.approx(1.0, abs=0.1)
    assert fit.camera is not None  # measured once from the pooled frames


def test_a_single_frame_is_refused():
    frame = make_fluorescence_series(1)[0]
    with pytest.raises(ValueError, match="at least 2 frames"):
        fit_series(frame.image[None], frame.microscope, RenderSettings(), None, geometry="open")
