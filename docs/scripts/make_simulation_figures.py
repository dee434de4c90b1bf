"""Figures of docs/simulation.md: kymographs of simulated trenches (supplement Fig. S2.1)
at three stacking settings, a lineage's sawtooth length trace, and 2D geometries.

Run ``python docs/scripts/make_simulation_figures.py``; images go to ``docs/images/``.
Cells are drawn as filled capsules straight from the simulation's cell states (no
optics), so the pictures show what the simulator itself produces.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import matplotlib
from _args import script_parser

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from napari_symbac.settings import AgarPadGeometry, SimulationSettings, TrenchGeometry
from napari_symbac.sim import FrameCells, Simulation, simulate

OUT = Path(__file__).resolve().parents[1] / "images"
PX_UM = 0.1  # drawing resolution


def _paint(frame: FrameCells, shape_px: tuple[int, int], origin_um=(0.0, 0.0)) -> np.ndarray:
    """Label image of the capsules of one frame (0 = background)."""
    h, w = shape_px
    yy, xx = np.mgrid[0:h, 0:w]
    x = (xx + 0.5) * PX_UM + origin_um[0]
    y = (yy + 0.5) * PX_UM + origin_um[1]
    image = np.zeros(shape_px, dtype=np.int64)
    p0, p1 = frame.poles_um()
    for cid, a, b, width in zip(frame.ids, p0, p1, frame.width_um):
        d = b - a
        t = np.clip(((x - a[0]) * d[0] + (y - a[1]) * d[1]) / max(d @ d, 1e-12), 0, 1)
        inside = np.hypot(x - a[0] - t * d[0], y - a[1] - t * d[1]) <= width / 2
        image[inside] = cid
    return image


def kymograph(sim: Simulation, every: int = 2, frames: int = 60) -> np.ndarray:
    """Frames of the trench side by side (time runs to the right)."""
    trench = sim.settings.trench
    shape = (int(trench.length_um / PX_UM), int(trench.width_um / PX_UM))
    tiles = []
    for frame in sim.frames[-frames * every :: every]:
        tiles.append(_paint(frame, shape))
        tiles.append(np.full((shape[0], 2), -1))
    return np.concatenate(tiles, axis=1)


def _show(ax, labels: np.ndarray, title: str) -> None:
    rng = np.random.default_rng(0)
    colours = rng.uniform(0.35, 1.0, size=(labels.max() + 2, 3))
    rgb = colours[labels % len(colours)]
    rgb[labels == 0] = 0.08
    rgb[labels == -1] = 1.0
    ax.imshow(rgb, interpolation="nearest", aspect="auto")
    ax.set_title(title, fontsize=9, loc="left")
    ax.set_xticks([])
    ax.set_yticks([])


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    base = SimulationSettings(n_frames=220, trench=TrenchGeometry(length_um=16.0), seed=2)
    cases = [
        ("gravity = 0, phys_iters = 15 (default)", base),
        ("gravity = -0.3: loose, cells drift out", dataclasses.replace(base, gravity=-0.3)),
        (
            "gravity = 0.5 in a 2 um trench: double loading",
            dataclasses.replace(
                base, gravity=0.5, trench=TrenchGeometry(length_um=16.0, width_um=2.0)
            ),
        ),
    ]
    fig, axes = plt.subplots(len(cases), 1, figsize=(10, 7.5))
    for ax, (title, settings) in zip(axes, cases):
        _show(ax, kymograph(simulate(settings)), title)
    axes[-1].set_xlabel("time → (every 2nd frame, 6 min apart); closed end at the top")
    fig.tight_layout()
    fig.savefig(OUT / "simulation_kymographs.png", dpi=110)
    plt.close(fig)

    sim = simulate(base)
    fig, ax = plt.subplots(figsize=(7, 2.6))
    record = sim.lineage[1]
    while True:
        trace = sim.trace(record.cell_id)
        ax.plot(trace.frames * base.frame_interval_min, trace.length_um, color="C0")
        kids = sorted(sim.children(record.cell_id))
        if not kids:
            break
        record = sim.lineage[kids[0]]
    ax.set_xlabel("time (min)")
    ax.set_ylabel("length (um)")
    ax.set_title("mother-cell lineage: sawtooth length trace (sizer)", fontsize=9, loc="left")
    fig.tight_layout()
    fig.savefig(OUT / "simulation_sawtooth.png", dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(9, 4.2))
    chamber = simulate(
        SimulationSettings(
            geometry="chamber",
            n_frames=120,
            n_founders=3,
            trench=TrenchGeometry(length_um=12.0, width_um=12.0),
        )
    )
    _show(axes[0], _paint(chamber.frames[-1], (120, 120)), "chamber (13.1), open at the bottom")
    pad = simulate(
        SimulationSettings(geometry="agar_pad", n_frames=60, agar_pad=AgarPadGeometry(40, 40))
    )
    _show(axes[1], _paint(pad.frames[-1], (400, 400)), "agar-pad colony (13.2)")
    fig.tight_layout()
    fig.savefig(OUT / "simulation_2d.png", dpi=110)
    plt.close(fig)
    print(f"wrote figures to {OUT}")


if __name__ == "__main__":
    script_parser(__doc__).parse_args()  # no arguments; --help prints the docstring above
    main()
