"""Are the scene fit's standard errors calibrated? Coverage of +-2 SE over seeds.

Run: ``python benchmarks/bench_fit_calibration.py [n_seeds] [--phase]`` (default 20).
Each seed renders the four-cell fluorescence field of ``tests/fit/_fit_synthetic.py``
(``--phase``: its three-cell phase trench, fitted from the wrong start ``START``) with
fresh camera noise, fits it with the camera estimated, and checks whether each true
parameter lies within two standard errors of its fitted value. A calibrated fit
covers about 95 % (the goal: at least 90 %). Prints a table; asserts nothing.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "fit"))

from _fit_synthetic import START, TRENCH, make_fluorescence_field, make_truth

from napari_symbac.fit import fit_scene
from napari_symbac.settings import RenderSettings

NAMES = ("x_um", "y_um", "angle_rad", "length_um")


def main() -> None:
    numbers = [a for a in sys.argv[1:] if a.isdigit()]
    seeds = int(numbers[0]) if numbers else 20
    phase = "--phase" in sys.argv
    inside: dict[str, list[bool]] = {}
    for seed in range(seeds):
        if phase:
            truth = make_truth(seed=100 + seed)
            fit = fit_scene(truth.image, truth.microscope, START, None)
            m = TRENCH.margin_um  # the truth is in trench coordinates, the fit in the image's
            cells = dataclasses.replace(
                truth.cells, x_um=truth.cells.x_um + m, y_um=truth.cells.y_um + m
            )
            truth = dataclasses.replace(truth, cells=cells)
        else:
            truth = make_fluorescence_field(seed=100 + seed)
            fit = fit_scene(
                truth.image,
                truth.microscope,
                RenderSettings(defocus_sigma_um=0.0),
                None,
                geometry="open",
            )
        if len(fit.cells) != len(truth.cells):
            print(f"seed {seed}: {len(fit.cells)} cells fitted, {len(truth.cells)} true")
            continue
        values = dict(zip(fit.parameter_names, fit.parameters))
        errors = dict(zip(fit.parameter_names, fit.standard_errors))
        for k in range(len(truth.cells)):
            d = np.hypot(fit.cells.x_um - truth.cells.x_um[k], fit.cells.y_um - truth.cells.y_um[k])
            cell = int(fit.cells.ids[int(np.argmin(d))])
            for name in NAMES:
                true = float(getattr(truth.cells, name)[k])
                key = f"cell{cell}.{name}"
                inside.setdefault(name, []).append(abs(values[key] - true) <= 2 * errors[key])
        if phase:
            for key in (
                "width_um",
                "cell_intensity",
                "media_intensity",
                "device_intensity",
                "defocus_sigma_um",
                "apodisation_sigma_um",
                "psf_offset",
            ):
                true = (
                    float(truth.cells.width_um[0])
                    if key == "width_um"
                    else getattr(truth.render, key)
                )
                inside.setdefault(key, []).append(abs(values[key] - true) <= 2 * errors[key])
            gain = fit.camera.sensitivity_adu_per_e
            print(
                f"seed {seed}: gain {gain:.3f} (true 2.9), reduced chi2 {fit.objective_after:.3f}"
            )
            continue
        # each cell's intensity I_c (1 + dbrightness): delta method on the covariance
        cov = np.linalg.pinv(fit.information, hermitian=True)
        names = list(fit.parameter_names)
        ic = names.index("cell_intensity")
        for k in range(len(fit.cells)):
            ib = names.index(f"cell{int(fit.cells.ids[k])}.dbrightness")
            grad = np.zeros(len(names))
            grad[ic] = 1 + fit.parameters[ib]
            grad[ib] = fit.parameters[ic]
            value = fit.parameters[ic] * (1 + fit.parameters[ib])
            se = float(np.sqrt(grad @ cov @ grad))
            true = truth.render.cell_intensity
            inside.setdefault("cell intensity", []).append(abs(value - true) <= 2 * se)
        shared = {
            "width_um": float(truth.cells.width_um[0]),
            "media_intensity": truth.render.media_intensity,
            "defocus_sigma_um": truth.render.defocus_sigma_um,
        }
        for key, true in shared.items():
            inside.setdefault(key, []).append(abs(values[key] - true) <= 2 * errors[key])
        gain = fit.camera.sensitivity_adu_per_e
        print(f"seed {seed}: gain {gain:.3f} (true 2.9), reduced chi2 {fit.objective_after:.3f}")
    print(f"\n| {'parameter':<18} | {'within 2 SE':>11} | {'cases':>5} |")
    print(f"|{'-' * 20}|{'-' * 13}|{'-' * 7}|")
    pooled = []
    for name, hits in inside.items():
        pooled += hits
        print(f"| {name:<18} | {100 * np.mean(hits):10.0f}% | {len(hits):5d} |")
    print(f"| {'all':<18} | {100 * np.mean(pooled):10.0f}% | {len(pooled):5d} |")


if __name__ == "__main__":
    main()
