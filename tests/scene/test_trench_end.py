"""A rounded closed end of the trench (``TrenchGeometry.closed_end``; docs/fitting.md)."""

from __future__ import annotations

import numpy as np
import pytest

from napari_symbac.fit import TrenchPlacement, fit_scene
from napari_symbac.optics import ForwardModel
from napari_symbac.scene import draw_scene
from napari_symbac.settings import (
    Camera,
    Microscope,
    RenderSettings,
    SimulationSettings,
    TrenchGeometry,
    from_dict,
    to_dict,
)
from napari_symbac.sim import FrameCells

MIC = Microscope()
RS = RenderSettings(psf_radius_px=12)
SQUARE = TrenchGeometry(length_um=6.0, width_um=1.4, depth_um=1.2, margin_um=0.8)
ROUND = TrenchGeometry(length_um=6.0, width_um=1.4, depth_um=1.2, margin_um=0.8, closed_end="round")


def _cells(y_um=(1.6, 4.2), x_um=0.7) -> FrameCells:
    n = len(y_um)
    return FrameCells(
        ids=np.arange(1, n + 1),
        x_um=np.full(n, x_um),
        y_um=np.asarray(y_um, float),
        angle_rad=np.zeros(n),
        length_um=np.full(n, 2.4),
        width_um=np.full(n, 0.9),
    )


def _at(scene, x_um, y_um):
    """Index of the render pixel at field-of-view position ``(x, y)`` (um)."""
    px, b = scene.pixel_size_um, scene.border_px
    return int(y_um / px) + b, int(x_um / px) + b


def test_closed_end_is_validated_and_round_trips():
    assert TrenchGeometry().closed_end == "square"
    with pytest.raises(ValueError, match="closed_end"):
        TrenchGeometry(closed_end="pointed")
    data = to_dict(SimulationSettings(trench=ROUND))
    assert data["trench"]["closed_end"] == "round"
    assert from_dict(SimulationSettings, data).trench == ROUND
    assert from_dict(TrenchGeometry, {"closed_end": "round"}).closed_end == "round"
    with pytest.raises(ValueError, match="closed_end"):
        TrenchPlacement(0.8, 1.4, 0.8, closed_end="pointed")


def test_square_end_is_the_default_bit_for_bit():
    explicit = TrenchGeometry(length_um=6.0, width_um=1.4, depth_um=1.2, margin_um=0.8)
    a = draw_scene(_cells(), explicit, MIC, RS)
    b = draw_scene(_cells(), SQUARE, MIC, RS)
    for name in ("cells", "media", "device", "labels"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    # The square end: media right into the corners.
    m = SQUARE.margin_um
    assert a.media[_at(a, m + 0.03, m + 0.03)] == 1.0
    assert a.device[_at(a, m + 0.03, m + 0.03)] == 0.0


def test_round_end_fills_the_corners_with_device():
    empty = _cells(y_um=(4.5,))
    sq = draw_scene(empty, SQUARE, MIC, RS)
    rd = draw_scene(empty, ROUND, MIC, RS)
    m, w = ROUND.margin_um, ROUND.width_um
    for x in (m + 0.05, m + w - 0.05):  # the top corners: device
        assert rd.device[_at(rd, x, m + 0.05)] == 1.0
        assert sq.device[_at(sq, x, m + 0.05)] == 0.0
    # Media on the axis just below the end, and across the full width below the cap.
    assert rd.media[_at(rd, m + w / 2, m + 0.05)] == 1.0
    assert rd.media[_at(rd, m + 0.05, m + w / 2 + 0.1)] == 1.0
    # Above the end and in the walls: device, as with the square end.
    assert rd.device[_at(rd, m + w / 2, m - 0.05)] == 1.0
    # Below the cap the two ends draw the same trench.
    row = _at(rd, 0.0, m + w / 2 + 3 * rd.pixel_size_um)[0]
    np.testing.assert_array_equal(rd.device[row:], sq.device[row:])
    # The cap's area: (1 - pi / 4) (w / 2)^2 of device in each corner.
    extra = float((rd.device - sq.device).sum()) * rd.pixel_size_um**2
    assert extra == pytest.approx(2 * (1 - np.pi / 4) * (w / 2) ** 2, rel=0.01)


def test_round_end_fractions_and_opl_are_physical():
    # A cell pushed into the end: it cannot sit inside the PDMS of the corners.
    scene = draw_scene(_cells(y_um=(1.1, 3.8)), ROUND, MIC, RS)
    for name in ("cells", "media", "device"):
        image = getattr(scene, name)
        assert image.min() >= 0.0
        assert image.max() <= 1.0
    np.testing.assert_allclose(scene.cells + scene.media + scene.device, 1.0, atol=1e-6)
    assert np.all(scene.cells <= 1.0 - scene.device + 1e-6)
    # Anti-aliased: partial pixels along the arc.
    cap = scene.device[: _at(scene, 0, 0.8 + 0.7)[0]]
    assert np.any((cap > 0.05) & (cap < 0.95))
    opl = scene.optical_path_length()
    n_media, n_pdms, n_cell = 1.333, 1.41, 1.39
    lo, hi = 1.2 * min(n_media, n_pdms, n_cell), 1.2 * max(n_media, n_pdms, n_cell)
    assert opl.min() >= lo - 1e-5
    assert opl.max() <= hi + 1e-5


def test_round_end_is_fitted_better_with_a_round_end():
    """A 96 x 46 crop drawn with a round end: the round-end fit has the lower chi-square."""
    mic = Microscope(pixel_size_um=0.065)
    render = RenderSettings(
        cell_intensity=1400.0,
        media_intensity=2600.0,
        device_intensity=900.0,
        apodisation_sigma_um=0.6,
        defocus_sigma_um=0.15,
        psf_offset=0.05,
        psf_radius_px=25,
    )
    camera = Camera()
    geometry = TrenchGeometry(
        length_um=96 * 0.065 - 0.75, width_um=1.5, depth_um=1.2, margin_um=0.75, closed_end="round"
    )
    cells = FrameCells(
        ids=np.array([1, 2]),
        x_um=np.array([0.75, 0.76]),
        y_um=np.array([1.5, 4.1]),
        angle_rad=np.zeros(2),
        length_um=np.array([2.3, 2.5]),
        width_um=np.full(2, 0.95),
    )
    scene = draw_scene(cells, geometry, mic, render, camera_shape=(96, 46))
    image = ForwardModel(mic, render, camera).render(scene, np.random.default_rng(3))
    start = TrenchPlacement(0.75, 1.5, 0.75, 1.2)
    chi = {}
    for end in ("square", "round"):
        fit = fit_scene(
            image,
            mic,
            render,
            camera,
            trench=start,
            closed_end=end,
            fit_optics=(),
            fit_curvature=False,
            irls_rounds=1,
            max_iterations=3,
        )
        assert fit.trench.closed_end == end
        chi[end] = fit.objective_after
    # Measured: 1.81 fitted square, 1.02 fitted round.
    assert chi["round"] < 0.8 * chi["square"]
    assert chi["round"] < 1.3
