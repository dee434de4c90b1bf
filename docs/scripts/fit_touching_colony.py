"""The touching fluorescent colony of docs/fitting.md ("Not done yet", time series).

Renders it (simulated pad, one colony of two founders, seed 0, frames 1-7, 96 x 96 px
drifting field; tests/fit/_series_synthetic.py) and prints, per frame, the number of
true cells in view and the number of blobs the fluorescence start
(``bright_instances``) finds and the finer seeds inside them. ``--fit`` also runs
``fit_series`` (minutes) and prints the fitted counts, the reseed moves, which frames
kept the start carried over from the previous frame and how many relations to the
previous frame (link, division, new) differ from the simulator's; ``--no-carry`` fits
every frame from its own start (``carry_cells=False``).

    PYTHONPATH=src python docs/scripts/fit_touching_colony.py [--fit [--no-carry]]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from _args import script_parser

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "fit"))

from _series_synthetic import (  # noqa: E402
    in_view,
    lineage_relations,
    render_pad_series,
    truth_relations,
)

from napari_symbac.fit.bright_start import bright_instances  # noqa: E402


def finer_seeds(image: np.ndarray, pixel_um: float, sigma_um: float = 0.12,
                ratio: float = 1.4) -> int:  # fmt: skip
    """Maxima of the image smoothed by ``sigma_um`` whose dynamics exceed ``ratio``
    (h-maxima of ``log(smooth - median)``), counted inside the start's blobs."""
    from scipy import ndimage
    from skimage.morphology import h_maxima

    blobs = bright_instances(image, pixel_um) > 0
    smooth = ndimage.gaussian_filter(np.asarray(image, float), sigma_um / pixel_um)
    height = np.log(np.maximum(smooth - np.median(smooth), 1.0))
    return int(ndimage.label(h_maxima(height, np.log(ratio)) & blobs)[0].max())


def main(fit_it: bool, carry: bool) -> None:
    truth = render_pad_series(seed=0, first=1, count=7, colonies=1)
    px = truth.microscope.pixel_size_um
    size_um = (truth.stack.shape[1] * px, truth.stack.shape[2] * px)
    frames = truth.simulation.frames[truth.first_frame : truth.first_frame + len(truth.stack)]
    seen = in_view(list(frames), truth.origins_um, size_um)
    starts = [int(bright_instances(image, px).max()) for image in truth.stack]
    print("true cells in view:", [len(c.ids) for c in seen])
    print("bright_instances blobs:", starts)
    print("finer seeds (0.12 um, 1.4):", [finer_seeds(image, px) for image in truth.stack])
    if fit_it:
        from napari_symbac.fit import fit_series
        from napari_symbac.settings import RenderSettings

        fit = fit_series(truth.stack, truth.microscope, RenderSettings(defocus_sigma_um=0.0),
                         None, geometry="open", carry_cells=carry)  # fmt: skip
        inside = [
            int(np.sum((f.cells.x_um >= 0) & (f.cells.x_um <= size_um[1])
                       & (f.cells.y_um >= 0) & (f.cells.y_um <= size_um[0])))
            for f in fit.frames
        ]  # fmt: skip
        print("fitted cells, centre in view:", inside)
        print("fitted cells, all (cells cut by the edge included):",
              [len(f.cells) for f in fit.frames])  # fmt: skip
        print("carried start kept:", list(fit.carried))
        print("moves:", [m for f in fit.frames for m in f.moves if "touching" in m])
        truth_ids, far = [], 0.0
        for t, frame in enumerate(fit.frames):
            # every simulated cell in the field's coordinates, those cut by its edge too
            cells = frames[t]
            x_um = cells.x_um - truth.origins_um[t][0]
            y_um = cells.y_um - truth.origins_um[t][1]
            distance = np.hypot(frame.cells.x_um[:, None] - x_um[None, :],
                                frame.cells.y_um[:, None] - y_um[None, :])  # fmt: skip
            nearest = distance.argmin(axis=1)
            far = max(far, float(distance.min(axis=1).max()))
            truth_ids.append(cells.ids[nearest])
        want = truth_relations(truth.simulation, truth_ids, first=truth.first_frame)
        got = lineage_relations(fit.lineage)
        wrong = sum(got[t][j] != r for t, step in enumerate(want) for j, r in step.items())
        total = sum(len(step) for step in want)
        print(f"relations to the previous frame wrong: {wrong} of {total}; "
              f"farthest fitted centre from its true cell: {far:.2f} um")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line: ``[--fit [--no-carry]]``."""
    parser = script_parser(__doc__)
    parser.add_argument("--fit", action="store_true", help="run fit_series too (minutes)")
    parser.add_argument(
        "--no-carry",
        action="store_true",
        help="with --fit: fit every frame from its own start (carry_cells=False)",
    )
    return parser.parse_args(argv)


if __name__ == "__main__":
    args = parse_args()
    main(args.fit, carry=not args.no_carry)
