"""Figures of the tracks that a series fit finds (docs/fitting.md, "Cell identity").

Run from the repository root::

    python docs/scripts/fit_series_tracks.py trench
    python docs/scripts/fit_series_tracks.py pad
    python docs/scripts/fit_series_tracks.py cli FIT_DIR IMAGE.tif OUT.png

``trench``: frames 11-14 of a simulated mother-machine run (seed 3, the run of
``tests/fit/test_lineage.py``) rendered with the fit tests' phase-contrast truth,
fitted jointly with :func:`~napari_symbac.fit.fit_series`; prints the tracks found
and the simulator's lineage, and writes ``docs/images/fit_series_tracks_trench.png``.

``pad``: frames 2-5 of a simulated fluorescence agar pad (seed 1, two founders
apart, the field drifting 0.2-0.4 um per frame; the series of
``tests/fit/test_lineage.py``) fitted with :func:`~napari_symbac.fit.fit_series`;
both founders divide after frame 1 into daughters lying end to end, which the septum
split cuts apart; writes ``docs/images/fit_series_tracks_pad.png``.

``cli``: the output folder of ``napari-symbac fit IMAGE --frames ...`` (its
``series.json`` and each frame's ``cells.json``) drawn over the frames of the image
it fitted, written to ``OUT.png``. The real images are read where they lie and never
copied.

Each panel is one frame (grey: square root of the image between its 0.5 and 99.8
percentiles); each fitted cell's
outline is drawn in its track's colour with the track's number, and a daughter's
number carries its mother's (``5<2``: track 5, daughter of track 2).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from _args import script_parser

ROOT = Path(__file__).resolve().parents[2]
IMAGES = ROOT / "docs" / "images"


def _outline_um(x, y, angle, length, width, points: int = 24) -> np.ndarray:
    """``(k, 2)`` (x, y) of a spherocylinder's outline."""
    u = np.array([np.sin(angle), np.cos(angle)])
    n = np.array([np.cos(angle), -np.sin(angle)])
    half = max(length - width, 0.0) / 2
    r = width / 2
    phi = np.linspace(-np.pi / 2, np.pi / 2, points)
    cap = r * (np.sin(phi)[:, None] * n + np.cos(phi)[:, None] * u)
    one = np.array([x, y]) + half * u + cap
    two = np.array([x, y]) - half * u - cap
    return np.concatenate([one, two, one[:1]])


def draw(images, cells, tracks, parents, pixel_um: float, out: Path, titles) -> None:
    """``images``: list of 2D frames; ``cells``: per frame a list of dicts with x_um,
    y_um, angle_rad, length_um, width_um; ``tracks``: per frame the track of each."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import patheffects

    palette = plt.get_cmap("tab10")
    rows, cols = images[0].shape
    # tall trench crops side by side; square fields two per row
    ncols = len(images) if rows > 2 * cols else min(2, len(images))
    nrows = -(-len(images) // ncols)
    panel = 3.0 if rows > 2 * cols else 5.0
    width = panel * cols / max(rows, cols)
    height = panel * rows / max(rows, cols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(ncols * width + 0.3, nrows * (height + 0.3)))
    axes = np.atleast_1d(axes).ravel()
    for ax in axes[len(images) :]:
        ax.axis("off")
    for ax, image, frame_cells, frame_tracks, title in zip(axes, images, cells, tracks, titles):
        low, high = np.percentile(image, [0.5, 99.8])
        extent = (0, cols * pixel_um, rows * pixel_um, 0)
        grey = np.sqrt(np.clip((np.asarray(image, float) - low) / (high - low), 0, 1))
        ax.imshow(grey, cmap="gray", vmin=0, vmax=1, extent=extent)
        for cell, track in zip(frame_cells, frame_tracks):
            colour = palette((int(track) - 1) % 10)
            xy = _outline_um(
                cell["x_um"], cell["y_um"], cell["angle_rad"], cell["length_um"], cell["width_um"]
            )
            ax.plot(xy[:, 0], xy[:, 1], color=colour, lw=1.2)
            label = f"{track}" + (f"<{parents[int(track)]}" if parents.get(int(track)) else "")
            stroke = [patheffects.withStroke(linewidth=2, foreground="black")]
            ax.text(cell["x_um"], cell["y_um"], label, color=colour, fontsize=9,
                    ha="center", va="center", fontweight="bold", path_effects=stroke)  # fmt: skip
        ax.set_xlim(0, cols * pixel_um)
        ax.set_ylim(rows * pixel_um, 0)
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(out, dpi=110 if max(rows, cols) <= 256 else 80)
    plt.close(fig)
    print(f"wrote {out}")


def trench() -> None:
    sys.path.insert(0, str(ROOT / "tests" / "fit"))
    from _fit_synthetic import START, TRENCH
    from _series_synthetic import render_trench_series, trench_simulation

    from napari_symbac.fit import fit_series

    simulation = trench_simulation(seed=3)
    truth = render_trench_series(simulation, first=11, count=4)
    fit = fit_series(truth.stack, truth.microscope, START, None, irls_rounds=2,
                     max_iterations=10, joint_iterations=5)  # fmt: skip
    print("tracks (track, first, last, parent):", fit.lineage.tracks.tolist())
    for t, (frame, cells) in enumerate(zip(fit.frames, truth.cells)):
        order = np.argsort(frame.cells.y_um)
        print(f"frame {t}: tracks top to bottom {fit.track_ids[t][order].tolist()}, "
              f"simulator ids top to bottom {cells.ids[np.argsort(cells.y_um)].tolist()}, "
              f"fitted y {np.round(frame.cells.y_um[order], 2).tolist()}, "
              f"true y {np.round(np.sort(cells.y_um) + TRENCH.margin_um, 2).tolist()}")  # fmt: skip
    print("simulator lineage:", [
        (c, r.parent_id, r.birth_frame - 11, r.end_frame - 11, r.fate)
        for c, r in simulation.lineage.items() if r.end_frame >= 11 and r.birth_frame <= 14
    ])  # fmt: skip
    titles = [f"frame {t} (sim. {t + 11})" for t in range(len(fit.frames))]
    _draw_fit(truth, fit, titles, IMAGES / "fit_series_tracks_trench.png")


def pad() -> None:
    sys.path.insert(0, str(ROOT / "tests" / "fit"))
    from _series_synthetic import render_pad_series

    from napari_symbac.fit import fit_series
    from napari_symbac.settings import RenderSettings

    truth = render_pad_series(seed=1, first=2, count=4)
    fit = fit_series(truth.stack, truth.microscope, RenderSettings(defocus_sigma_um=0.0),
                     None, geometry="open")  # fmt: skip
    print("tracks (track, first, last, parent):", fit.lineage.tracks.tolist())
    for t, frame in enumerate(fit.frames):
        cells = truth.simulation.frames[truth.first_frame + t]
        print(f"frame {t}: {len(frame.cells)} fitted, {len(cells)} true; moves {frame.moves}")
    titles = [f"frame {t} (sim. {t + truth.first_frame})" for t in range(len(fit.frames))]
    _draw_fit(truth, fit, titles, IMAGES / "fit_series_tracks_pad.png")


def _draw_fit(truth, fit, titles: list[str], out: Path) -> None:
    """The figure of a fitted series of rendered frames: the fitted cells by track."""
    cells = [
        [dict(zip(("x_um", "y_um", "angle_rad", "length_um", "width_um"), values))
         for values in zip(f.cells.x_um, f.cells.y_um, f.cells.angle_rad, f.cells.length_um,
                           f.cells.width_um)]
        for f in fit.frames
    ]  # fmt: skip
    parents = {int(t): int(p) for t, _b, _e, p in fit.lineage.tracks}
    draw(list(truth.stack), cells, fit.track_ids, parents, truth.microscope.pixel_size_um,
         out, titles)  # fmt: skip


def from_cli(fit_dir: Path, image: Path, out: Path) -> None:
    import tifffile

    series = json.loads((fit_dir / "series.json").read_text())
    stack = tifffile.imread(image)
    frames = series["frames"]
    lineage = series["lineage"]
    cells, tracks, pixel_um = [], [], None
    for frame in frames:
        table = json.loads((fit_dir / f"frame_{frame:04d}" / "cells.json").read_text())
        cells.append(table["cells"])
        tracks.append([c["track"] for c in table["cells"]])
        settings = (fit_dir / f"frame_{frame:04d}" / "settings.yaml").read_text()
        for line in settings.splitlines():
            if line.strip().startswith("pixel_size_um:"):
                pixel_um = float(line.split(":")[1])
    parents = {row["track"]: row["parent"] for row in lineage["tracks"]}
    print("tracks:", lineage["tracks"])
    draw([stack[f] for f in frames], cells, tracks, parents, pixel_um, out,
         [f"frame {f}" for f in frames])  # fmt: skip


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line: ``trench``, ``pad`` or ``cli FIT_DIR IMAGE.tif OUT.png``."""
    parser = script_parser(__doc__)
    modes = parser.add_subparsers(dest="mode", required=True, metavar="{trench,pad,cli}")
    modes.add_parser("trench", help="fit a simulated mother-machine run, draw its tracks")
    modes.add_parser("pad", help="fit a simulated fluorescence agar pad, draw its tracks")
    cli = modes.add_parser("cli", help="draw the tracks of a napari-symbac fit --frames run")
    cli.add_argument(
        "fit_dir",
        type=Path,
        metavar="FIT_DIR",
        help="the --out folder of napari-symbac fit IMAGE --frames ...",
    )
    cli.add_argument("image", type=Path, metavar="IMAGE", help="the image it fitted")
    cli.add_argument("out", type=Path, metavar="OUT", help="the PNG to write")
    args = parser.parse_args(argv)
    if args.mode == "cli" and not (args.fit_dir / "series.json").is_file():
        cli.error(
            f"{args.fit_dir / 'series.json'} not found: pass the folder that "
            "napari-symbac fit IMAGE --frames ... --out FIT_DIR wrote"
        )
    if args.mode == "cli" and not args.image.is_file():
        cli.error(f"{args.image} not found: pass the image that napari-symbac fit fitted")
    return args


if __name__ == "__main__":
    args = parse_args()
    if args.mode == "trench":
        trench()
    elif args.mode == "pad":
        pad()
    else:
        from_cli(args.fit_dir, args.image, args.out)
