"""The settings form round-trips every settings class without changing a value."""

from __future__ import annotations

import pytest

pytest.importorskip("magicgui", reason="the [gui] extra is not installed")

from napari_symbac._widgets._forms import SettingsForm
from napari_symbac.settings import (
    Camera,
    Microscope,
    OutlineGeometry,
    RenderSettings,
    SimulationSettings,
)


@pytest.mark.parametrize(
    "settings",
    [
        SimulationSettings(),
        SimulationSettings(
            geometry="outline",
            outline=OutlineGeometry(polylines_um=(((0, 0), (0, 10)), ((3, 0), (3, 10)))),
        ),
        Microscope(condenser="Ph2"),
        RenderSettings(),
        Camera(),
    ],
)
def test_form_round_trip(settings, qtbot):
    form = SettingsForm(type(settings), settings)
    assert form.value == settings


def test_form_edits_and_validates(qtbot):
    form = SettingsForm(SimulationSettings)
    form.n_frames.value = 12
    form.trench.width_um.value = 2.0
    value = form.value
    assert value.n_frames == 12
    assert value.trench.width_um == 2.0
    form.cell_width_um.value = 3.0
    with pytest.raises(ValueError, match="does not fit in a trench"):
        _ = form.value
