"""Figures for docs/rendering.md: synthetic vs real trenches, Fig. S1.3 and S1.4.

Reads the real micrographs from ../shared/data/real (GPL data: never copied into
the repository) and writes PNGs to docs/images/. Run from the repository root:
``python docs/scripts/make_rendering_figures.py``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import matplotlib
from _args import checked_real_data, real_data_from_environment, script_parser

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import tifffile

from napari_symbac.fit import class_statistics, fit_scene
from napari_symbac.optics import ForwardModel
from napari_symbac.optics.validation import membrane_dye_width, otsu_width
from napari_symbac.pipeline import apply_cell_brightness
from napari_symbac.settings import Camera, Microscope, RenderSettings

ROOT = Path(__file__).resolve().parents[2]
REAL = real_data_from_environment()
OUT = ROOT / "docs" / "images"

#: Optics of the 100x oil comparison; the rest is fitted (fit_scene) to the real trench.
MICROSCOPE = Microscope()  # 100x oil, NA 1.45, 0.065 um/px, 0.65 um, Ph3
CAMERA = Camera()
#: ColiCoords ds3 fluorescence (MIT), camera offset kept; pixel size assumed 0.08 um.
FLUO = REAL / "colicoords" / "test_data" / "ds3"


def stretch(image: np.ndarray, low: float = 500, high: float = 6000) -> np.ndarray:
    return np.clip((image.astype(float) - low) / (high - low), 0, 1)


def fluorescence_intensities() -> dict[str, float]:
    """Eq. 2 class means of the ColiCoords fluorescence frame 0 (cells: mask; media: the rest)."""
    from scipy.ndimage import binary_dilation

    flu = tifffile.imread(FLUO / "flu.tif")[0].astype(float)
    mask = tifffile.imread(FLUO / "binary.tif")[0] > 0
    media = ~binary_dilation(mask, iterations=4)
    labels = np.where(mask, 1, np.where(media, 2, 0)).astype(np.uint8)
    stats = class_statistics(flu, labels, required=("cell", "media"))
    return {"cell": stats["cell"].mean, "media": stats["media"].mean}


def comparison() -> None:
    real = tifffile.imread(REAL / "ecoli_100x_oil_exponential.tiff")
    start = time.perf_counter()
    fit = fit_scene(real, MICROSCOPE, RenderSettings(), CAMERA, closed_end="round")
    seconds = time.perf_counter() - start
    render = fit.render
    rng = np.random.default_rng(1)
    phase = ForwardModel(MICROSCOPE, render, CAMERA).render(fit.scene, rng)
    flu = fluorescence_intensities()
    # The ColiCoords background holds the camera offset: render with baseline 0 and
    # the media class mean as the media intensity (no device in an agar-pad field).
    fluo_mic = Microscope(modality="fluorescence", wavelength_um=0.53)
    fluo_render = RenderSettings(
        cell_intensity=flu["cell"], media_intensity=flu["media"], device_intensity=flu["media"]
    )
    fluo_camera = Camera(baseline_adu=0.0)
    fluo_scene = apply_cell_brightness(fit.scene, cv=0.3, seed=1)
    fluo = ForwardModel(fluo_mic, fluo_render, fluo_camera).render(fluo_scene, rng)
    rms = float(np.sqrt(np.mean(fit.residual**2)))
    fig, axes = plt.subplots(1, 5, figsize=(8, 7.5))
    lim = float(np.abs(fit.residual).max())
    panels = [
        ("real (100x oil)", stretch(real), "gray", None),
        ("fitted synthetic\nphase (+noise)", stretch(phase), "gray", None),
        (f"residual\n(rms {rms:.0f} ADU)", fit.residual, "RdBu_r", (-lim, lim)),
        ("synthetic fluo\n(ColiCoords I)", fluo, "gray", None),
        ("instance mask", fit.scene.camera_labels(), "nipy_spectral", None),
    ]
    for ax, (title, image, cmap, clim) in zip(axes, panels):
        kw = {"vmin": clim[0], "vmax": clim[1]} if clim else {}
        ax.imshow(image, cmap=cmap, interpolation="nearest", **kw)
        ax.set_title(title, fontsize=8)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(OUT / "rendering_comparison.png", dpi=110)
    plt.close(fig)
    # Column profiles: real vs fitted synthetic phase.
    fig, ax = plt.subplots(figsize=(5, 3))
    ax.plot(real[40:].mean(0), label="real")
    ax.plot(phase[40:].mean(0), label="fitted synthetic (+noise)")
    ax.plot(fit.synthetic[40:].mean(0), ":", label="fitted synthetic (clean)")
    ax.set_xlabel("column (camera px)")
    ax.set_ylabel("mean ADU (rows 40-255)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(OUT / "rendering_profiles.png", dpi=110)
    plt.close(fig)
    print(f"fit_scene: {fit.n_evaluations} renders, {seconds:.0f} s")
    print(f"pixel objective (reduced chi2) {fit.objective_before:.2f} -> {fit.objective_after:.2f}")
    for name, (before, after) in fit.terms.items():
        print(f"  term {name}: {before:.4g} -> {after:.4g}")
    print(
        f"residual mean {fit.residual.mean():+.1f} ADU, rms {rms:.0f} ADU, "
        f"real s.d. {real.std():.0f}"
    )
    for name in (
        "cell_intensity",
        "media_intensity",
        "device_intensity",
        "apodisation_sigma_um",
        "defocus_sigma_um",
        "ring_contrast",
        "psf_offset",
    ):
        print(f"  {name} = {getattr(render, name):.4g}")
    print("trench", fit.trench)
    print("cells", len(fit.cells.ids), "width", np.round(fit.cells.width_um, 3).tolist())
    print("lengths", np.round(fit.cells.length_um, 2).tolist())
    print("curvature", np.round(fit.curvature_um, 3).tolist())
    print("fluorescence class means (ADU, offset included)", flu)


def benchmarks() -> None:
    widths = np.round(np.arange(0.6, 1.41, 0.1), 2)
    s42 = Microscope(wavelength_um=0.75, numerical_aperture=0.97, refractive_index=1.0)
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for psf in ("born-wolf", "gaussian"):
        err = [membrane_dye_width(w, s42, psf).relative_error * 100 for w in widths]
        axes[0].plot(widths, err, "o-", label=f"{psf} (lambda 0.75, NA 0.97)")
        print("S1.3", psf, dict(zip(widths.tolist(), np.round(err, 1).tolist())))
    err = [membrane_dye_width(w, Microscope(), "born-wolf").relative_error * 100 for w in widths]
    axes[0].plot(widths, err, "s--", label="born-wolf (lambda 0.65, NA 1.45)")
    axes[0].set_xlabel("true width (um)")
    axes[0].set_ylabel("width error (%)")
    axes[0].set_title("Fig. S1.3: membrane-dye inter-peak width")
    axes[0].legend(fontsize=7)
    cases = [
        ("ours, ring contrast 0", RenderSettings(ring_contrast=0.0), {}, "o-"),
        ("ours, ring contrast 1", RenderSettings(ring_contrast=1.0), {}, "o-"),
        ("ours, ring contrast 2", RenderSettings(ring_contrast=2.0), {}, "o-"),
        ("ours, rc 1, flat-top cell", RenderSettings(ring_contrast=1.0), {"profile": "flat"}, "x:"),
        (
            "SyMBac-like kernel, apod. 0.22 um",
            RenderSettings(apodisation_sigma_um=0.22),
            {"kernel": "symbac"},
            "s--",
        ),
        (
            "SyMBac-like kernel, apod. 0.31 um",
            RenderSettings(apodisation_sigma_um=0.31),
            {"kernel": "symbac"},
            "s--",
        ),
    ]
    for label, render, kw, style in cases:
        offset = [w - otsu_width(w, Microscope(), render, **kw) for w in widths]
        axes[1].plot(widths, offset, style, label=label)
        print("S1.4", label, dict(zip(widths.tolist(), np.round(offset, 3).tolist())))
    axes[1].set_xlabel("true width (um)")
    axes[1].set_ylabel("true - Otsu width (um)")
    axes[1].set_title("Fig. S1.4: Otsu offset (100x phase)")
    axes[1].axhline(0, color="k", lw=0.5)
    axes[1].set_ylim(-0.12, 0.26)
    axes[1].legend(fontsize=6, ncol=2, loc="lower center")
    fig.tight_layout()
    fig.savefig(OUT / "benchmarks_s1.png", dpi=110)
    plt.close(fig)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line: no arguments (``--help`` prints the docstring above); the real
    recordings are read from $NAPARI_SYMBAC_REAL_DATA, else ../shared/data/real."""
    parser = script_parser(__doc__)
    args = parser.parse_args(argv)
    checked_real_data(
        parser, REAL, "ecoli_100x_oil_exponential.tiff and colicoords", given="environment"
    )
    return args


if __name__ == "__main__":
    parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    comparison()
    benchmarks()
