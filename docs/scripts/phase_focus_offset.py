"""The pupil's defocus on the Omnipose colonies: does it bring the fitted cells to the real ones?

Run: ``python docs/scripts/phase_focus_offset.py REAL_DATA_DIR`` (from the repository
root; it imports ``phase_class_medians`` beside it). For each Omnipose colony
(MIT, ``REAL_DATA_DIR/omnipose``): ``calibrate`` with its masks as
``docs/scripts/phase_class_medians.py`` does (0.55 um, 1 um cells, 160 px crop, 25 renders),
then the partially coherent fit of its crop once more, from the calibrated optics, with
``focus_offset_um`` freed as well, started at -0.2, 0 and +0.2 um (25 renders each). Prints,
per start, the fitted focus, the reduced chi-square on the crop and the normalised class
medians (``calibrate.compare_images``) of the real masks rendered with those optics, beside
the real image's and the calibrated optics' own.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
from _args import add_real_data, checked_real_data, script_parser
from phase_class_medians import calibrated_colony

from napari_symbac.calibrate import compare_images
from napari_symbac.fit import fit_parameters
from napari_symbac.fit.parameters import DEFAULT_FIT_PARTIALLY_COHERENT
from napari_symbac.optics import ForwardModel
from napari_symbac.scene import scene_from_masks


def main(real: Path) -> None:
    folder = real / "omnipose"
    print("| image | focus start (um) | fitted focus (um) | reduced chi-square | cells | bg |")
    print("|---|---|---|---|---|---|")
    for path in sorted(folder.glob("Sample*.png")):
        image, masks, cal = calibrated_colony(path)
        s = cal.settings
        depth, width = s.simulation.trench.depth_um, s.simulation.cell_width_um
        # the phase per unit of the masks' material, as fitted (calibrate rescales it
        # for the drawn pad's depth)
        phase = s.render.cell_phase_rad * width / depth
        fitted = dataclasses.replace(s.render, cell_phase_rad=phase)
        real = compare_images(image, masks, image, masks)
        print(f"| {path.stem} | real | | | {real.cells[0]:.3f} | {real.background[0]:.3f} |")
        crop_scene = scene_from_masks(masks[cal.crop], s.microscope, fitted)
        whole_scene = scene_from_masks(masks, s.microscope, fitted)
        rows = [("calibrated (in focus)", fitted, cal.fit_chi2[1])]
        for start in (-0.2, 0.0, 0.2):
            result = fit_parameters(
                image[cal.crop], None, crop_scene, s.microscope,
                dataclasses.replace(fitted, focus_offset_um=start), s.camera,
                terms=("pixel",), fit=(*DEFAULT_FIT_PARTIALLY_COHERENT, "focus_offset_um"),
                max_evaluations=25, global_search=False,
            )  # fmt: skip
            rows.append((f"{start:+.1f}", result.render, result.objective_after))
            for warning in result.warnings:
                print(f"  warning ({start:+.1f}): {warning}")
        for label, render, chi2 in rows:
            own = ForwardModel(s.microscope, render, s.camera).render(
                whole_scene, np.random.default_rng(0)
            )
            c = compare_images(image, masks, own, masks)
            print(
                f"| {path.stem} | {label} | {render.focus_offset_um:+.3f} | {chi2:.2f} | "
                f"{c.cells[1]:.3f} | {c.background[1]:.3f} |",
                flush=True,
            )


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line: ``REAL_DATA_DIR``."""
    parser = script_parser(__doc__)
    add_real_data(
        parser, required=True, help="the folder of the project's real recordings (omnipose inside)"
    )
    args = parser.parse_args(argv)
    checked_real_data(parser, args.real / "omnipose", "the Omnipose colonies")
    return args


if __name__ == "__main__":
    main(parse_args().real)
