"""Simulation rows: a mother-machine trench and an agar-pad colony grown to many cells.

Stand-ins until the simulation helper's ``measure_*`` functions are registered under
the same names (``sim_trench``, ``sim_colony``) with the same keys.
"""

from __future__ import annotations

import time

import numpy as np

from napari_symbac.bench.config import BenchConfig
from napari_symbac.bench.registry import register
from napari_symbac.bench.timing import fft_floor_s, trench_kernel

__all__ = ["SYMBAC_TRENCH", "colony_frame_shape", "sim_colony", "sim_trench"]

#: The trench SyMBac 0.5.2 simulates in the same run (15 um x 1.4 um).
SYMBAC_TRENCH = {"length_um": 15.0, "width_um": 1.4}


def _trench_frame_shape(simulation) -> tuple[int, int]:
    from napari_symbac.scene import draw_scene
    from napari_symbac.settings import Microscope, RenderSettings

    scene = draw_scene(
        simulation.frames[-1], simulation.settings.trench, Microscope(), RenderSettings()
    )
    return scene.shape


@register("sim_trench")
def sim_trench(config: BenchConfig) -> dict[str, float]:
    """Frames of a 15 um trench (SyMBac's settings): ``frame_s`` per frame, ``fft_s``."""
    from napari_symbac.settings import SimulationSettings, TrenchGeometry
    from napari_symbac.sim import Simulator

    settings = SimulationSettings(
        n_frames=config.trench_frames, trench=TrenchGeometry(**SYMBAC_TRENCH), seed=0
    )
    start = time.perf_counter()
    simulator = Simulator(settings)
    for _ in simulator.iter_frames():
        pass
    seconds = time.perf_counter() - start
    simulation = simulator.result()
    return {
        "frame_s": seconds / config.trench_frames,
        "frames": float(config.trench_frames),
        "fft_s": fft_floor_s(_trench_frame_shape(simulation), trench_kernel()),
    }


def colony_frame_shape(cells, pixel_size_um: float = 0.065, upsample: int = 3) -> tuple[int, int]:
    """Render-resolution frame that holds ``cells`` (their bounding box, a 2 um margin,
    the PSF border of radius 50)."""
    reach = np.asarray(cells.length_um) / 2 + 2.0
    x, y = np.asarray(cells.x_um), np.asarray(cells.y_um)
    width = (x + reach).max() - (x - reach).min()
    height = (y + reach).max() - (y - reach).min()
    return (
        int(np.ceil(height / pixel_size_um)) * upsample + 100,
        int(np.ceil(width / pixel_size_um)) * upsample + 100,
    )


@register("sim_colony")
def sim_colony(config: BenchConfig) -> dict[str, float]:
    """An agar-pad colony grown from one cell to ``config.colony_cells[-1]`` cells.

    For each size ``N`` of ``config.colony_cells`` (index ``i``): ``frame_s_i``, the
    median seconds of the three frames after the colony first reaches ``N`` cells;
    ``cell_frame_s_i``, that per cell; ``fft_s_i``, the FFT floor of a frame that holds
    the colony then; ``cells_i``, its cells.
    """
    from napari_symbac.settings import AgarPadGeometry, SimulationSettings
    from napari_symbac.sim import Simulator

    target = config.colony_cells[-1]
    side_um = float(max(40.0, 2.5 * np.sqrt(target * 2.5)))
    settings = SimulationSettings(
        geometry="agar_pad",
        n_frames=100_000,
        agar_pad=AgarPadGeometry(field_width_um=side_um, field_height_um=side_um),
        seed=0,
    )
    simulator = Simulator(settings)
    frames = simulator.iter_frames()
    result: dict[str, float] = {}
    kernel = trench_kernel()
    for i, size in enumerate(config.colony_cells):
        while True:
            frame = next(frames)
            if len(frame) >= size:
                break
        times, counts = [], []
        for _ in range(3):
            start = time.perf_counter()
            frame = next(frames)
            times.append(time.perf_counter() - start)
            counts.append(len(frame))
        result[f"frame_s_{i}"] = float(np.median(times))
        result[f"cells_{i}"] = float(np.median(counts))
        result[f"cell_frame_s_{i}"] = result[f"frame_s_{i}"] / result[f"cells_{i}"]
        result[f"fft_s_{i}"] = fft_floor_s(colony_frame_shape(frame), kernel, repeats=3)
    return result
