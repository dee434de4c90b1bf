"""Agar-pad founders: several colonies at random centres and scattered single cells."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from napari_symbac.settings import AgarPadGeometry, SimulationSettings
from napari_symbac.sim import simulate
from napari_symbac.sim.geometry import make_layout


def _settings(**pad) -> SimulationSettings:
    return SimulationSettings(
        geometry="agar_pad",
        n_founders=6,
        n_frames=12,
        agar_pad=AgarPadGeometry(40.0, 30.0, **pad),
        seed=11,
    )


def _layout(settings: SimulationSettings):
    return make_layout(settings, np.random.default_rng(settings.seed))


def test_one_colony_keeps_the_centred_grid():
    layout = _layout(_settings())
    xy = np.array([f[:2] for f in layout.founders])
    assert len(xy) == 6
    np.testing.assert_allclose(xy.mean(axis=0), (20.0, 15.0), atol=3.0)
    assert layout.gravity_centres_um == ((20.0, 15.0),)


def test_colonies_and_scattered_cells_spread_over_the_field():
    settings = _settings(n_colonies=3, scattered_cells=4, colony_separation_um=9.0)
    layout = _layout(settings)
    assert len(layout.founders) == 6 + 4
    centres = layout.gravity_centres_um
    assert len(centres) == 3 + 4
    colonies, scattered = centres[:3], centres[3:]
    for a, b in itertools.combinations(colonies, 2):
        assert math.dist(a, b) >= 9.0
    for a, b in itertools.product(scattered, colonies):
        assert math.dist(a, b) >= 9.0
    for a, b in itertools.combinations(scattered, 2):
        assert math.dist(a, b) >= 4.5
    for x, y in centres:
        assert 3.0 <= x <= 37.0
        assert 3.0 <= y <= 27.0
    # not a tight grid at the centre: the founders span most of the field
    xy = np.array([f[:2] for f in layout.founders])
    assert np.ptp(xy[:, 0]) > 15.0
    assert np.ptp(xy[:, 1]) > 10.0
    # each colony's two founders sit together around their centre
    for k, centre in enumerate(colonies):
        pair = xy[2 * k : 2 * k + 2]
        assert np.all(np.hypot(*(pair - centre).T) <= settings.cell_max_length_um)


def test_same_seed_same_layout_other_seed_other_layout():
    settings = _settings(n_colonies=2, scattered_cells=3)
    assert _layout(settings).founders == _layout(settings).founders
    other = _layout(dataclasses.replace(settings, seed=12))
    assert other.founders != _layout(settings).founders


def test_colonies_grow_apart_and_stay_in_the_field():
    simulation = simulate(_settings(n_colonies=2, scattered_cells=2, colony_separation_um=15.0))
    last = simulation.frames[-1]
    assert last.ids.size > 10  # they grew
    assert np.all((last.x_um >= 0) & (last.x_um <= 40) & (last.y_um >= 0) & (last.y_um <= 30))
    again = simulate(_settings(n_colonies=2, scattered_cells=2, colony_separation_um=15.0))
    np.testing.assert_array_equal(
        np.asarray(again.frames[-1].x_um), np.asarray(simulation.frames[-1].x_um)
    )


def test_impossible_layouts_are_rejected():
    with pytest.raises(ValueError, match="cannot place"):
        _layout(_settings(n_colonies=5, colony_separation_um=30.0))
    # refused by the settings themselves, so a form says so before any run starts
    with pytest.raises(ValueError, match=r"n_colonies=7 exceeds SimulationSettings\.n_founders=6"):
        _settings(n_colonies=7)
    with pytest.raises(ValueError, match="n_colonies must be an integer"):
        AgarPadGeometry(n_colonies=0)
    with pytest.raises(ValueError, match="edge_margin_um"):
        AgarPadGeometry(10.0, 10.0, edge_margin_um=5.0)
