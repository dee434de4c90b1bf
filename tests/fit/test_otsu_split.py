"""The Otsu start splits touching cells at bright septa (septum profile split)."""

from __future__ import annotations

import numpy as np
import pytest
from _fit_synthetic import PIXEL_UM, TRUTH, make_cells

import napari_symbac.fit.start as start
from napari_symbac.fit import otsu_cells
from napari_symbac.optics import ForwardModel
from napari_symbac.scene import draw_scene
from napari_symbac.settings import Camera, Microscope, TrenchGeometry

#: A 160 x 46 crop of the 1.5 um trench of the other fit tests.
LONG_TRENCH = TrenchGeometry(
    length_um=160 * PIXEL_UM - 0.75, width_um=1.5, depth_um=1.2, margin_um=0.75
)
LENGTHS = np.array([2.2, 2.5, 2.0, 2.4])
#: The poles of neighbours overlap by 0.2 um: the cells touch along a neck ~0.6 um wide.
OVERLAP_UM = 0.2


def _touching(seed: int):
    y = 0.1 + np.cumsum(LENGTHS) - LENGTHS / 2 - OVERLAP_UM * np.arange(4)
    cells = make_cells(
        y_um=y,
        x_um=[0.75, 0.72, 0.78, 0.74],
        angle_rad=[0.03, -0.05, 0.06, -0.02],
        length_um=LENGTHS,
    )
    microscope = Microscope(pixel_size_um=PIXEL_UM)
    scene = draw_scene(cells, LONG_TRENCH, microscope, TRUTH)
    image = ForwardModel(microscope, TRUTH, Camera()).render(scene, np.random.default_rng(seed))
    return cells, image.astype(float), microscope


@pytest.mark.parametrize("seed", [1, 2])
def test_touching_cells_are_split_at_their_septa(seed, monkeypatch):
    cells, image, microscope = _touching(seed)
    found, _, _, instances = otsu_cells(image, microscope)
    assert len(found) == 4
    assert instances.max() == 4
    true_x = cells.x_um + LONG_TRENCH.margin_um
    true_y = cells.y_um + LONG_TRENCH.margin_um
    order = np.argsort(found.y_um)
    distance = np.hypot(found.x_um[order] - true_x, found.y_um[order] - true_y)
    assert np.all(distance < 0.3), distance
    # Without the septum split the same image is one region (equal rods, wrong centres).
    monkeypatch.setattr(start, "_split_at_septa", lambda instances, *args, **kw: instances)
    plain, _, _, plain_instances = otsu_cells(image, microscope)
    assert plain_instances.max() < 4
    if len(plain) == 4:
        plain_distance = np.hypot(plain.x_um - true_x, plain.y_um - true_y)
        assert plain_distance.max() > 0.3


def test_single_cells_are_not_split(truth):
    """Three separate cells stay three regions: texture inside a cell is no septum."""
    found, _, _, instances = otsu_cells(truth.image.astype(float), truth.microscope)
    assert len(found) == 3
    assert instances.max() == 3


def test_septum_cuts_respect_prominence_and_length():
    x = np.arange(100, dtype=float)
    profile = (
        1000 + 200 * np.exp(-0.5 * ((x - 50) / 2) ** 2) + 30 * np.exp(-0.5 * ((x - 25) / 2) ** 2)
    )
    noise = np.full(x.size, 3.0)
    assert start._septum_cuts(profile, noise, 100.0, 20) == [50]
    assert start._septum_cuts(profile, noise, 10.0, 20) == [25, 50]  # low bar: both
    assert start._septum_cuts(profile, noise, 10.0, 30) == [50]  # 25 leaves < 30 bins
    assert start._septum_cuts(profile, np.full(x.size, 50.0), 10.0, 20) == []  # noise


def test_prominent_maxima_are_scipy_find_peaks():
    """The start's own peak finder gives find_peaks' peaks and prominences, flat tops
    and ties included (it saves importing scipy.signal)."""
    from scipy.signal import find_peaks

    rng = np.random.default_rng(0)
    for trial in range(400):
        profile = rng.normal(size=int(rng.integers(1, 60)))
        if trial % 2:
            profile = np.repeat(np.round(profile * 2) / 2, rng.integers(1, 4))  # flat tops
        min_prominence = float(rng.choice([0.0, 0.3, 1.0]))
        peaks, props = find_peaks(profile, prominence=min_prominence)
        found, prominences = start.prominent_maxima(profile, min_prominence)
        np.testing.assert_array_equal(found, peaks)
        np.testing.assert_allclose(prominences, props["prominences"], rtol=0, atol=1e-12)
