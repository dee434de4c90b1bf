"""Simulation rows: a mother-machine trench and an agar-pad colony grown to many cells.

:func:`measure_trench` times a trench run; :func:`measure_colony_scaling` the cost per
cell-frame of one colony at several sizes, the sizes interleaved (1.0 for the ratio of
the largest to the smallest is linear in cells). ``napari-symbac bench`` registers
``sim_trench`` (a 15 um trench, SyMBac's settings) and ``sim_colony``.
"""

from __future__ import annotations

import pickle
import statistics
import time

import numpy as np

from napari_symbac.bench.config import BenchConfig
from napari_symbac.bench.registry import register
from napari_symbac.bench.timing import fft_floor_s

__all__ = [
    "COLONY_FIELD_UM",
    "COLONY_SIZES",
    "SYMBAC_TRENCH",
    "colony_frame_shape",
    "grow_colony",
    "measure_colony",
    "measure_colony_scaling",
    "measure_trench",
    "sim_colony",
    "sim_trench",
]

#: Side of the agar-pad field the benchmark colonies grow in: a 4000-cell colony
#: (about 75 um across) stays well inside it, so no cell leaves the field.
COLONY_FIELD_UM = 250.0
COLONY_SIZES = (400, 1000, 4000)
#: The trench SyMBac 0.5.2 simulates in the same run (15 um x 1.4 um).
SYMBAC_TRENCH = {"length_um": 15.0, "width_um": 1.4}


def measure_trench(frames: int = 250, length_um: float = 25.0, seed: int = 0) -> dict:
    """Simulate a mother-machine trench (1.4 um wide) for ``frames`` frames.

    Returns
    -------
    dict
        ``frames``, ``seconds`` (wall time of the whole run), ``frames_per_s``,
        ``cell_frames`` (cells summed over frames), ``final_cells``.
    """
    from napari_symbac.settings import SimulationSettings, TrenchGeometry
    from napari_symbac.sim import Simulator

    settings = SimulationSettings(
        n_frames=frames, trench=TrenchGeometry(length_um=length_um, width_um=1.4), seed=seed
    )
    start = time.perf_counter()
    simulator = Simulator(settings)
    cells = 0
    for frame in simulator.iter_frames():
        cells += len(frame)
    seconds = time.perf_counter() - start
    return {
        "frames": frames,
        "seconds": seconds,
        "frames_per_s": frames / seconds,
        "cell_frames": cells,
        "final_cells": len(frame),
    }


def grow_colony(n_cells: int, seed: int = 0):
    """An agar-pad :class:`~napari_symbac.sim.Simulator` (one founder, a
    :data:`COLONY_FIELD_UM` square field) run until its colony has ``n_cells`` cells
    or more; returns ``(simulator, seconds)``."""
    from napari_symbac.settings import AgarPadGeometry, SimulationSettings
    from napari_symbac.sim import Simulator

    if n_cells < 1:
        raise ValueError(f"n_cells must be >= 1, got {n_cells}")
    settings = SimulationSettings(
        geometry="agar_pad",
        n_frames=100_000,
        agar_pad=AgarPadGeometry(COLONY_FIELD_UM, COLONY_FIELD_UM),
        seed=seed,
    )
    start = time.perf_counter()
    simulator = Simulator(settings)
    for frame in simulator.iter_frames():
        if len(frame) >= n_cells:
            break
    return simulator, time.perf_counter() - start


def _time_frames(simulator, frames: int) -> dict:
    cell_frames = 0
    start, start_cpu = time.perf_counter(), time.process_time()
    for _ in range(frames):
        frame = simulator.step()
        cell_frames += len(frame)
    seconds = time.perf_counter() - start
    cpu_seconds = time.process_time() - start_cpu
    return {
        "frames": frames,
        "seconds": seconds,
        "cpu_seconds": cpu_seconds,
        "cell_frames": cell_frames,
        "ms_per_cell_frame": 1e3 * seconds / cell_frames,
        "cpu_ms_per_cell_frame": 1e3 * cpu_seconds / cell_frames,
        "frames_per_s": frames / seconds,
        "final_cells": len(frame),
    }


def measure_colony(n_cells: int, frames: int = 3, seed: int = 0) -> dict:
    """Grow an agar-pad colony to ``n_cells`` cells (not timed), then time ``frames``
    more frames.

    Returns
    -------
    dict
        ``n_cells`` (asked), ``cells`` (when timing started), ``frames``, ``seconds``,
        ``cell_frames`` (cells summed over the timed frames), ``ms_per_cell_frame``,
        ``frames_per_s``, ``final_cells``, ``grow_seconds`` (the untimed growth).
    """
    simulator, grow_seconds = grow_colony(n_cells, seed)
    cells = len(simulator.result().frames[-1])
    row = _time_frames(simulator, frames)
    return {"n_cells": n_cells, "cells": cells, **row, "grow_seconds": grow_seconds}


def measure_colony_scaling(
    sizes: tuple[int, ...] = COLONY_SIZES, frames: int = 3, rounds: int = 3, seed: int = 0
) -> dict:
    """Cost per cell-frame of one agar-pad colony at several sizes, interleaved.

    The colony is grown once through all ``sizes``; its simulator is saved (pickled)
    when it first reaches each size. Then, ``rounds`` times, ``frames`` frames are
    timed from each saved state in turn, so that a change in the machine's load hits
    every size alike. (A restored simulator has the same cells and contacts, but pymunk
    rebuilds its spatial index, so its trajectory departs from an uninterrupted run's in
    the last bits; the work per frame is the same.)

    Returns
    -------
    dict
        ``sizes``: per size, ``cells`` (when timing started), ``ms_per_cell_frame``
        (best round), ``ms_per_cell_frame_median``, ``ms_per_cell_frame_rounds``,
        ``cpu_ms_per_cell_frame`` and ``cpu_ms_per_cell_frame_median`` (the same in CPU
        time of the process: on a machine with more jobs than cores, wall time also
        counts the time spent waiting for a core),
        ``frames_per_s`` (best round), ``frames_per_s_median``, ``render_shape`` (the
        render frame that holds the colony then); ``ratio``: best cost per cell-frame at the
        largest size over that at the smallest (1.0 is linear in cells);
        ``ratio_median``: the same from the medians; ``cpu_ratio`` and
        ``cpu_ratio_median``: the same in CPU time; ``grow_seconds``.
    """
    sizes = tuple(sorted(sizes))
    simulator, grow_seconds = grow_colony(sizes[0], seed)
    saved: dict[int, bytes] = {}
    cells_at: dict[int, int] = {}
    shapes: dict[int, tuple[int, int]] = {}
    cells = len(simulator.result().frames[-1])
    start = time.perf_counter()
    for size in sizes:
        while cells < size:
            cells = len(simulator.step())
        saved[size], cells_at[size] = pickle.dumps(simulator), cells
        shapes[size] = colony_frame_shape(simulator.result().frames[-1])
    grow_seconds += time.perf_counter() - start
    times: dict[int, list[dict]] = {size: [] for size in sizes}
    for _ in range(rounds):
        for size in sizes:
            times[size].append(_time_frames(pickle.loads(saved[size]), frames))
    out: dict = {"sizes": {}, "grow_seconds": grow_seconds, "frames": frames, "rounds": rounds}
    for size in sizes:
        per = [row["ms_per_cell_frame"] for row in times[size]]
        cpu = [row["cpu_ms_per_cell_frame"] for row in times[size]]
        out["sizes"][size] = {
            "cells": cells_at[size],
            "ms_per_cell_frame": min(per),
            "ms_per_cell_frame_median": statistics.median(per),
            "ms_per_cell_frame_rounds": per,
            "cpu_ms_per_cell_frame": min(cpu),
            "cpu_ms_per_cell_frame_median": statistics.median(cpu),
            "frames_per_s": max(row["frames_per_s"] for row in times[size]),
            "frames_per_s_median": statistics.median(row["frames_per_s"] for row in times[size]),
            "render_shape": shapes[size],
        }
    small, large = out["sizes"][sizes[0]], out["sizes"][sizes[-1]]
    out["ratio"] = large["ms_per_cell_frame"] / small["ms_per_cell_frame"]
    out["ratio_median"] = large["ms_per_cell_frame_median"] / small["ms_per_cell_frame_median"]
    out["cpu_ratio"] = large["cpu_ms_per_cell_frame"] / small["cpu_ms_per_cell_frame"]
    out["cpu_ratio_median"] = (
        large["cpu_ms_per_cell_frame_median"] / small["cpu_ms_per_cell_frame_median"]
    )
    return out


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


def _trench_frame_shape(length_um: float, width_um: float) -> tuple[int, int]:
    """Render frame of a trench (it does not depend on the cells in it)."""
    from napari_symbac.bench.cases_render import trench_cells
    from napari_symbac.scene import draw_scene
    from napari_symbac.settings import Microscope, RenderSettings, TrenchGeometry

    trench = TrenchGeometry(length_um=length_um, width_um=width_um)
    cells = trench_cells(0.0)
    keep = cells.y_um < length_um - 1.6
    one = type(cells)(**{k: v[keep] for k, v in vars(cells).items()})
    return draw_scene(one, trench, Microscope(), RenderSettings()).shape


@register("sim_trench")
def sim_trench(config: BenchConfig) -> dict[str, float]:
    """:func:`measure_trench` of a 15 um trench (SyMBac's settings): ``frame_s`` per
    frame, ``fft_s`` the floor of its render frame."""
    run = measure_trench(config.trench_frames, SYMBAC_TRENCH["length_um"])
    return {
        "frame_s": run["seconds"] / run["frames"],
        "frames": float(run["frames"]),
        "fft_s": fft_floor_s(_trench_frame_shape(**SYMBAC_TRENCH)),
    }


@register("sim_colony")
def sim_colony(config: BenchConfig) -> dict[str, float]:
    """:func:`measure_colony_scaling` at ``config.colony_cells`` (index ``i``).

    ``cell_frame_s_i`` (seconds per cell-frame, median of the rounds), ``frame_s_i``
    (seconds per frame), ``cells_i``, ``fft_s_i`` (the floor of a frame that holds the
    colony then), ``ratio`` (cost per cell-frame, largest / smallest size) and
    ``cpu_ratio`` (the same in CPU time, steadier on a machine with more jobs than cores).
    """
    out = measure_colony_scaling(config.colony_cells, frames=3, rounds=1 if config.quick else 2)
    result: dict[str, float] = {}
    for i, size in enumerate(sorted(config.colony_cells)):
        row = out["sizes"][size]
        result[f"cell_frame_s_{i}"] = row["ms_per_cell_frame_median"] / 1e3
        result[f"frame_s_{i}"] = 1.0 / row["frames_per_s_median"]
        result[f"cells_{i}"] = float(row["cells"])
        result[f"fft_s_{i}"] = fft_floor_s(row["render_shape"], repeats=3)
    result["ratio"] = out["ratio_median"]
    result["cpu_ratio"] = out["cpu_ratio_median"]
    return result
