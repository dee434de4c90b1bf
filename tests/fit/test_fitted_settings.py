"""The simulation a fit implies (``fit.fitted_settings.fitted_simulation``)."""

from __future__ import annotations

import numpy as np
import pytest

from napari_symbac.fit import fit_scene
from napari_symbac.fit.fitted_settings import fitted_simulation
from napari_symbac.pipeline import render_simulation
from napari_symbac.settings import PipelineSettings, SimulationSettings, TrenchGeometry
from napari_symbac.sim import simulate


def test_a_narrow_trench_of_narrow_cells_is_kept_whole():
    """Cells 0.8 um wide in a 1.1 um trench (as DeLTA's): the defaults' 1 um cells do
    not fit the fitted trench, the fitted cells do (found as a user: the trench was
    checked against the defaults' cells first, and the whole fit was dropped). Its
    closed end, 1.5 um below the image's top edge, stays there (found as a user: the
    export's closed end sat at the sides' margin, 15 px too high on DeLTA's trench)."""
    narrow = SimulationSettings(
        n_frames=30,
        seed=4,
        cell_width_um=0.8,
        width_var_um2=0.0,
        trench=TrenchGeometry(length_um=10.0, width_um=1.1, margin_um=0.6, top_margin_um=1.5),
    )
    simulation = simulate(narrow)
    settings = PipelineSettings(simulation=narrow)
    frame = render_simulation(simulation, settings).images[-1].astype(np.float64)
    fit = fit_scene(frame, settings.microscope, settings.render, settings.camera,
                    geometry="trench", max_iterations=4)  # fmt: skip
    with pytest.raises(ValueError, match="does not fit in a trench"):
        SimulationSettings(trench=fit.trench_geometry(frame.shape, 0.065))
    fitted = fitted_simulation(SimulationSettings(), fit, frame.shape, 0.065)
    assert fitted.trench.width_um == pytest.approx(1.1, abs=0.1)
    assert fitted.cell_width_um == pytest.approx(0.8, abs=0.1)
    assert fitted.trench.width_um + 2 * fitted.trench.margin_um == pytest.approx(
        frame.shape[1] * 0.065
    )
    # the closed end stays where it was fitted (not at the sides' margin)
    assert fitted.trench.top_margin_um == pytest.approx(1.5, abs=0.1)
    assert fitted.trench.length_um + fitted.trench.top_margin_um == pytest.approx(
        frame.shape[0] * 0.065
    )
