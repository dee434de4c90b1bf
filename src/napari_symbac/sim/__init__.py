"""Agent-based growth simulation with rigid-body physics (supplement section 2, 13).

>>> from napari_symbac.settings import SimulationSettings
>>> from napari_symbac.sim import simulate
>>> sim = simulate(SimulationSettings(n_frames=3))
>>> len(sim.frames)
3
"""

from napari_symbac.sim.cells import (
    CellTrace,
    FrameCells,
    LineageRecord,
    Simulation,
    spherocylinder_length_um,
    spherocylinder_volume_um3,
)
from napari_symbac.sim.geometry import read_dxf_walls
from napari_symbac.sim.io import FORMAT_VERSION, load_simulation, save_simulation
from napari_symbac.sim.simulator import Simulator, simulate

__all__ = [
    "FORMAT_VERSION",
    "CellTrace",
    "FrameCells",
    "LineageRecord",
    "Simulation",
    "Simulator",
    "load_simulation",
    "read_dxf_walls",
    "save_simulation",
    "simulate",
    "spherocylinder_length_um",
    "spherocylinder_volume_um3",
]
