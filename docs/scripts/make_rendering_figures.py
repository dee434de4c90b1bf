"""Figures for docs/rendering.md: synthetic vs real trenches, Fig. S1.3 and S1.4.

Reads the real micrographs from ../shared/data/real (GPL data: never copied into
the repository) and writes PNGs to docs/images/. Run from the repository root:
``python docs/scripts/make_rendering_figures.py``.
"""

from __future__ import annotations

import os
from pathlib import Path
from types import SimpleNamespace

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import tifffile

from napari_symbac.optics import ForwardModel
from napari_symbac.optics.validation import membrane_dye_width, otsu_width
from napari_symbac.scene import draw_scene, vary_cell_brightness
from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry

ROOT = Path(__file__).resolve().parents[2]
REAL = Path(os.environ.get("NAPARI_SYMBAC_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))
OUT = ROOT / "docs" / "images"

#: Parameters used for the phase-contrast comparison (printed into the figure title).
TRENCH = TrenchGeometry(length_um=15.84, width_um=1.5, depth_um=1.2, margin_um=0.745)
MICROSCOPE = Microscope()  # 100x oil, NA 1.45, 0.065 um/px, 0.65 um, Ph3
RENDER = RenderSettings(
    cell_intensity=700.0,
    media_intensity=4200.0,
    device_intensity=950.0,
    apodisation_sigma_um=0.35,
    ring_contrast=1.5,
)
CAMERA = Camera(baseline_adu=100.0, sensitivity_adu_per_e=2.9, dark_noise_e=8.0)


def cells(seed: int) -> SimpleNamespace:
    rng = np.random.default_rng(seed)
    lengths = rng.uniform(2.4, 3.6, 6)
    y = np.cumsum(lengths + 0.05) - lengths / 2 + 0.1
    keep = y - lengths / 2 < TRENCH.length_um
    n = int(keep.sum())
    return SimpleNamespace(
        ids=np.arange(1, n + 1),
        x_um=np.full(n, 0.75) + rng.normal(0, 0.03, n),
        y_um=y[keep],
        angle_rad=rng.normal(0, 0.03, n),
        length_um=lengths[keep],
        width_um=rng.normal(1.0, 0.03, n),
    )


def stretch(image: np.ndarray, low: float = 500, high: float = 6000) -> np.ndarray:
    return np.clip((image.astype(float) - low) / (high - low), 0, 1)


def comparison() -> None:
    real = tifffile.imread(REAL / "ecoli_100x_oil_exponential.tiff")
    rng = np.random.default_rng(1)
    scene = draw_scene(cells(3), TRENCH, MICROSCOPE, RENDER)
    phase = ForwardModel(MICROSCOPE, RENDER, CAMERA).render(scene, rng)
    fluo_mic = Microscope(modality="fluorescence", wavelength_um=0.53)
    fluo_render = RenderSettings(cell_intensity=3000, media_intensity=60, device_intensity=20)
    fluo_scene = vary_cell_brightness(scene, rng, cv=0.3)
    fluo = ForwardModel(fluo_mic, fluo_render, CAMERA).render(fluo_scene, rng)
    fig, axes = plt.subplots(1, 4, figsize=(6.5, 7.5))
    panels = [
        ("real (100x oil)", stretch(real)),
        ("synthetic phase", stretch(phase)),
        ("synthetic fluo", stretch(fluo, 100, fluo.max())),
        ("instance mask", scene.camera_labels()),
    ]
    for ax, (title, image) in zip(axes, panels):
        ax.imshow(
            image, cmap="gray" if "mask" not in title else "nipy_spectral", interpolation="nearest"
        )
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(OUT / "rendering_comparison.png", dpi=110)
    plt.close(fig)
    # Column profiles: real vs synthetic phase.
    fig, ax = plt.subplots(figsize=(5, 3))
    ax.plot(real[40:].mean(0), label="real")
    ax.plot(phase[40:].mean(0), label="synthetic")
    ax.set_xlabel("column (camera px)")
    ax.set_ylabel("mean ADU (rows 40-255)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(OUT / "rendering_profiles.png", dpi=110)
    plt.close(fig)
    print("real: device", real[:, :4].mean(), "peak column", real[40:].mean(0).max())
    print("synthetic: device", phase[:, :4].mean(), "peak column", phase[40:].mean(0).max())


def benchmarks() -> None:
    widths = np.round(np.arange(0.6, 1.41, 0.1), 2)
    s42 = Microscope(wavelength_um=0.75, numerical_aperture=0.97, refractive_index=1.0)
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.2))
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
    for gamma in (0.0, 1.0, 2.0):
        render = RenderSettings(ring_contrast=gamma)
        offset = [w - otsu_width(w, Microscope(), render) for w in widths]
        axes[1].plot(widths, offset, "o-", label=f"ring contrast {gamma}")
        print("S1.4 gamma", gamma, dict(zip(widths.tolist(), np.round(offset, 3).tolist())))
    axes[1].set_xlabel("true width (um)")
    axes[1].set_ylabel("true - Otsu width (um)")
    axes[1].set_title("Fig. S1.4: Otsu offset (100x phase)")
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(OUT / "benchmarks_s1.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    OUT.mkdir(parents=True, exist_ok=True)
    comparison()
    benchmarks()
