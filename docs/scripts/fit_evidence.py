"""Evidence for docs/fitting.md: recovery on synthetic trenches and the fit of a real one.

Run from the repository root::

    python docs/scripts/fit_evidence.py [REAL_DATA_DIR]

Prints the recovery errors of ``fit_parameters`` and ``fit_scene`` on a 128 x 46 trench
rendered by the project's own model (camera noise, ~900 e- background), then fits the
real 100x trench ``ecoli_100x_oil_exponential.tiff`` (GPL-2 SyMBac sample data, read from
``../shared/data/real`` and never copied into the repository) and writes
``docs/images/fit_real_trench.png``: real | start (Otsu) | fitted | residual.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import tifffile
from _args import parse_real_data

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "fit"))

from _fit_synthetic import START, TRENCH, make_truth  # noqa: E402

from napari_symbac.fit import fit_parameters, fit_scene, scene_classes  # noqa: E402
from napari_symbac.fit.scene_fit import before_after_montage  # noqa: E402
from napari_symbac.settings import Camera, Microscope, RenderSettings  # noqa: E402

NAMES = ("cell_intensity", "media_intensity", "device_intensity")


def recovery() -> None:
    truth = make_truth()
    classes = scene_classes(truth.scene)
    print("## Recovery on a synthetic 128 x 46 trench (truth known)\n")
    print("| fit | parameter | truth | fitted | error |")
    print("|---|---|---|---|---|")
    for label, terms in (
        ("fit_parameters, pixel", ("pixel",)),
        ("fit_parameters, statistics", None),
    ):
        result = fit_parameters(
            truth.image, classes, truth.scene, truth.microscope, START, truth.camera, terms=terms
        )
        for name in (*NAMES, "apodisation_sigma_um", "defocus_sigma_um", "psf_offset"):
            t, f = getattr(truth.render, name), getattr(result.render, name)
            err = f"{100 * (f - t) / t:+.1f} %" if name != "psf_offset" else f"{f - t:+.3f}"
            print(f"| {label} | {name} | {t:g} | {f:.4g} | {err} |")
    scene = fit_scene(
        truth.image,
        truth.microscope,
        RenderSettings(apodisation_sigma_um=1.0, defocus_sigma_um=0.05, psf_offset=0.0),
        truth.camera,
    )
    order = np.argsort(scene.cells.y_um)
    true = truth.cells
    dw = (scene.cells.width_um[order] - true.width_um) * 1000
    dl = (scene.cells.length_um[order] - true.length_um) * 1000
    ow = (scene.otsu_width_um - true.width_um) * 1000
    ol = (scene.initial_cells.length_um - true.length_um) * 1000
    for name in NAMES:
        t, f = getattr(truth.render, name), getattr(scene.render, name)
        print(f"| fit_scene | {name} | {t:g} | {f:.4g} | {100 * (f - t) / t:+.1f} % |")
    print(f"| fit_scene | width error per cell (nm) | | {np.round(dw, 1).tolist()} | |")
    print(f"| fit_scene | length error per cell (nm) | | {np.round(dl, 1).tolist()} | |")
    print(f"| Otsu | width error per cell (nm) | | {np.round(ow, 1).tolist()} | |")
    print(f"| Otsu | length error per cell (nm) | | {np.round(ol, 1).tolist()} | |")
    print(
        f"\nfit_scene pixel chi2 {scene.objective_before:.3f} -> {scene.objective_after:.3f}; "
        f"trench width {scene.trench.width_um:.3f} um (truth {TRENCH.width_um})\n"
    )


def real(data_dir: Path) -> None:
    image = tifffile.imread(data_dir / "ecoli_100x_oil_exponential.tiff")
    microscope = Microscope(pixel_size_um=0.065)
    start = time.perf_counter()
    result = fit_scene(image, microscope, RenderSettings(), Camera())
    seconds = time.perf_counter() - start
    print("## Real trench: ecoli_100x_oil_exponential.tiff (256 x 46)\n")
    print(f"- cells fitted: {len(result.cells)}; renders: {result.n_evaluations}; {seconds:.0f} s")
    print(
        f"- pixel objective (reduced chi-square, camera variance): "
        f"{result.objective_before:.1f} -> {result.objective_after:.1f}"
    )
    print(
        f"- residual: mean {result.residual.mean():+.0f} ADU, rms "
        f"{np.sqrt(np.mean(result.residual**2)):.0f} ADU (image s.d. {image.std():.0f})"
    )
    print(f"- fitted trench: {result.trench}")
    r = result.render
    print(
        f"- fitted optics: I_c {r.cell_intensity:.0f}, I_m {r.media_intensity:.0f}, "
        f"I_t {r.device_intensity:.0f} ADU; apodisation {r.apodisation_sigma_um:.3f} um, "
        f"defocus {r.defocus_sigma_um:.3f} um, psf_offset {r.psf_offset:.3f}"
    )
    print(f"- model-based (shared) width: {result.cells.width_um[0]:.3f} um")
    print(f"- Otsu widths: {np.round(result.otsu_width_um, 3).tolist()} um")
    print(f"- fitted lengths: {np.round(result.cells.length_um, 2).tolist()} um")
    figure = before_after_montage(image, result)
    figure = np.repeat(np.repeat(figure, 2, axis=0), 2, axis=1)
    path = ROOT / "docs" / "images" / "fit_real_trench.png"
    iio.imwrite(path, figure)
    print(f"- figure: {path.relative_to(ROOT)}")


if __name__ == "__main__":
    data = parse_real_data(__doc__, "ecoli_100x_oil_exponential.tiff")
    recovery()
    real(data)
