"""Series rendered from the simulator's own runs: known identities, divisions and exits."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from _fit_synthetic import PIXEL_UM, TRENCH, TRUTH

from napari_symbac.optics import ForwardModel
from napari_symbac.scene import draw_scene
from napari_symbac.settings import Camera, Microscope, SimulationSettings
from napari_symbac.sim import FrameCells, Simulation, simulate


@dataclass(frozen=True)
class SeriesTruth:
    simulation: Simulation
    first_frame: int
    cells: list[FrameCells]  # the simulator's cells of each rendered frame (trench coordinates)
    stack: np.ndarray  # (T, 128, 46) uint16
    microscope: Microscope


def trench_simulation(seed: int = 3, n_frames: int = 40) -> Simulation:
    """A mother-machine run in the 128 x 46 px test trench: 5 min frames, ~25 min doubling."""
    return simulate(
        SimulationSettings(
            n_frames=n_frames,
            trench=TRENCH,
            frame_interval_min=5.0,
            cell_width_um=0.95,
            seed=seed,
        )
    )


def render_trench_series(
    simulation: Simulation, first: int, count: int, seed: int = 7
) -> SeriesTruth:
    """Frames ``first .. first + count - 1`` of a trench run, rendered with the fit tests'
    phase-contrast truth (:data:`~_fit_synthetic.TRUTH`) and camera noise."""
    microscope = Microscope(pixel_size_um=PIXEL_UM)
    model = ForwardModel(microscope, TRUTH, Camera())
    rng = np.random.default_rng(seed)
    cells = simulation.frames[first : first + count]
    images = [model.render(draw_scene(c, TRENCH, microscope, TRUTH), rng) for c in cells]
    return SeriesTruth(simulation, first, list(cells), np.stack(images), microscope)
