"""Scaling of the cost with frames, cells, image size and PSF radius, and its plot.

Measured once per run (with ``--out``), beside the table: the trench simulation at a
quarter, half and all of ``config.trench_frames`` frames; the colony's frame cost at
the table's cell counts; drawing + masks of open fields of 256, 512 and 1024 camera px
at one density; and the trench frame's per-frame path at PSF radii 20 to 80 render px.
Each render point has its FFT floor beside it.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from napari_symbac.bench.config import BenchConfig

__all__ = ["measure_scaling", "plot_scaling"]

RADII_PX = (20, 35, 50, 80)
FIELD_SIDES_PX = (256, 512, 1024)


def measure_scaling(config: BenchConfig, rounds: list[dict[str, Any]]) -> dict[str, Any]:
    """The four scaling series (lists of numbers, JSON-ready)."""
    from napari_symbac.bench import cases_render, cases_sim

    data: dict[str, Any] = {}
    frames = [max(4, config.trench_frames // 4), max(8, config.trench_frames // 2)]
    frames.append(config.trench_frames)
    data["frames"] = {"frames": frames, "seconds": []}
    for n in frames:
        run = cases_sim.sim_trench(dataclasses.replace(config, trench_frames=n))
        data["frames"]["seconds"].append(run["frame_s"] * n)

    colony = [r["sim_colony"] for r in rounds if "frame_s_0" in r.get("sim_colony", {})]
    if colony:
        data["cells"] = {
            "cells": [colony[0][f"cells_{i}"] for i in range(3)],
            "frame_s": [float(np.median([c[f"frame_s_{i}"] for c in colony])) for i in range(3)],
            "fft_s": [float(np.median([c[f"fft_s_{i}"] for c in colony])) for i in range(3)],
        }

    size_px, n_cells = cases_render.FIELD_CASES[0]
    density = n_cells / size_px**2
    data["size"] = {"side_px": list(FIELD_SIDES_PX), "frame_s": [], "fft_s": []}
    for side in FIELD_SIDES_PX:
        count = max(1, round(density * side**2))
        run = cases_render.measure_field_draw(side, count, rounds=2 if config.quick else 3)
        data["size"]["frame_s"].append(run["draw_masks_s"])
        data["size"]["fft_s"].append(run["fft_floor_s"])

    data["psf"] = {"radius_px": list(RADII_PX), "frame_s": [], "fft_s": []}
    for radius in RADII_PX:
        run = cases_render.measure_trench_frame(max(5, config.render_frames), radius)
        data["psf"]["frame_s"].append(run["frame_s"])
        data["psf"]["fft_s"].append(run["fft_floor_s"])
    return data


def plot_scaling(data: dict[str, Any], path: str | Path) -> Path | None:
    """A 2 x 2 figure of ``data`` as a PNG, or ``None`` without matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    fig, axes = plt.subplots(2, 2, figsize=(10, 7.5), constrained_layout=True)
    ax = axes[0, 0]
    f = data["frames"]
    ax.plot(f["frames"], f["seconds"], "o-", label="trench simulation")
    slope = f["seconds"][-1] / f["frames"][-1]
    ax.plot(f["frames"], [slope * n for n in f["frames"]], "k:", label="linear")
    ax.set(xlabel="frames", ylabel="seconds", title="cost vs frames (15 um trench)")
    ax.legend()
    ax = axes[0, 1]
    if "cells" in data:
        c = data["cells"]
        ax.loglog(c["cells"], c["frame_s"], "o-", label="colony simulation, per frame")
        ax.loglog(c["cells"], c["fft_s"], "s--", label="FFT floor of a frame holding it")
        linear = [c["frame_s"][0] * n / c["cells"][0] for n in c["cells"]]
        ax.loglog(c["cells"], linear, "k:", label="linear in cells")
        ax.legend()
    ax.set(xlabel="cells", ylabel="seconds", title="cost vs cells (agar-pad colony)")
    ax = axes[1, 0]
    s = data["size"]
    pixels = [side**2 for side in s["side_px"]]
    ax.loglog(pixels, s["frame_s"], "o-", label="draw + masks")
    ax.loglog(pixels, s["fft_s"], "s--", label="FFT floor")
    ax.set(xlabel="camera pixels (256², 512², 1024² fields)", ylabel="seconds per frame",
           title="drawing cost vs image size (same cell density)")
    ax.legend()
    ax = axes[1, 1]
    p = data["psf"]
    ax.plot(p["radius_px"], [1e3 * v for v in p["frame_s"]], "o-", label="draw + render + masks")
    ax.plot(p["radius_px"], [1e3 * v for v in p["fft_s"]], "s--", label="FFT floor")
    ax.set(xlabel="PSF radius (render px)", ylabel="ms per frame",
           title="cost vs PSF radius (256 x 46 trench)")
    ax.legend()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
