"""The real 100x trench's residual against the noise, model addition by addition.

Run from the repository root::

    python docs/scripts/fit_trench_residual.py [REAL_DATA_DIR]

Fits ``ecoli_100x_oil_exponential.tiff`` (GPL-2 SyMBac sample data, read from
``../shared/data/real``, never copied) with the round closed end and the camera
measured from the image, once per model (flat light; the illumination surface of
degree 2, 4, 6; per-cell brightness and widths), and prints per model the reduced
chi-square, the residual rms over the camera noise's rms, the cell count and the
time. Then the noise check (the standardised residual's power at high spatial
frequencies, 1 for white noise of the camera's variance) and the share of
chi-square by region. Writes ``docs/images/fit_trench_residual.png``: real |
fitted | residual of the plain fit and of the best one, on one scale.
"""

from __future__ import annotations

import time
from pathlib import Path

import matplotlib
from _args import parse_real_data

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import tifffile
from scipy import ndimage

from napari_symbac.fit import fit_scene
from napari_symbac.settings import Microscope, RenderSettings

ROOT = Path(__file__).resolve().parents[2]
MODELS = {
    "flat light (main)": {},
    "+ illumination, degree 2": {"illumination_order": 2},
    "+ illumination, degree 4": {"illumination_order": 4},
    "+ illumination, degree 6": {"illumination_order": 6},
    "per-cell brightness + widths": {"per_cell_brightness": True, "width_sd_um": 0.1},
    "degree 4 + per-cell brightness": {"illumination_order": 4, "per_cell_brightness": True},
    "degree 4 + per-cell brightness + widths": {
        "illumination_order": 4,
        "per_cell_brightness": True,
        "width_sd_um": 0.1,
    },
}


def _variance(fit) -> np.ndarray:
    cam = fit.camera
    mean = np.maximum(fit.synthetic.astype(float) - cam.baseline_adu, 0.0)
    return cam.sensitivity_adu_per_e * mean + (cam.sensitivity_adu_per_e * cam.dark_noise_e) ** 2


def _white_power(z: np.ndarray) -> float:
    """Mean periodogram of ``z`` above 0.35 cycles/px (1 for white unit noise)."""
    power = np.abs(np.fft.fft2(z - z.mean())) ** 2 / z.size
    fy = np.fft.fftfreq(z.shape[0])[:, None]
    fx = np.fft.fftfreq(z.shape[1])[None, :]
    return float(power[np.hypot(fy, fx) > 0.35].mean())


def _regions(fit, z2: np.ndarray) -> dict[str, float]:
    sc, shape = fit.scene, fit.synthetic.shape
    u, b = sc.upsample, sc.border_px

    def cam(a):
        a = np.asarray(a, float)[b:-b, b:-b]
        return a.reshape(shape[0], u, shape[1], u).mean(axis=(1, 3))

    cells, device = cam(sc.cells), cam(sc.device)
    inside = cells > 0.5
    signed = np.where(
        inside,
        -ndimage.distance_transform_edt(inside),
        ndimage.distance_transform_edt(~inside),
    )
    regions = {
        "cell interiors (> 2 px inside)": signed < -2,
        "cell edges (+-2 px)": (signed >= -2) & (signed <= 2),
        "media > 2 px from cells": (signed > 2) & (device < 0.05),
        "trench walls (device 0.05-0.95)": (device >= 0.05) & (device <= 0.95),
        "PDMS (device > 0.95)": device > 0.95,
    }
    total = z2.sum()
    return {
        k: (float(m.mean()), float(z2[m].mean()), float(z2[m].sum() / total))
        for k, m in regions.items()
    }


def main(real_dir: Path) -> None:
    image = tifffile.imread(real_dir / "ecoli_100x_oil_exponential.tiff")
    microscope = Microscope(pixel_size_um=0.065)
    fits = {}
    print("| model | reduced chi-square | residual rms (ADU) | rms / noise rms | cells | s |")
    print("|---|---|---|---|---|---|")
    for name, options in MODELS.items():
        t0 = time.perf_counter()
        fit = fit_scene(image, microscope, RenderSettings(), closed_end="round", **options)
        seconds = time.perf_counter() - t0
        fits[name] = fit
        rms = float(np.sqrt(np.mean(fit.residual.astype(float) ** 2)))
        noise = float(np.sqrt(_variance(fit).mean()))
        print(
            f"| {name} | {fit.objective_after:.2f} | {rms:.0f} | {rms / noise:.2f} | "
            f"{len(fit.cells)} | {seconds:.0f} |"
        )
        if fit.at_bounds:
            print(f"  at bounds: {', '.join(fit.at_bounds)}")
        if fit.illumination_order:
            terms = ", ".join(f"{c:+.3f}" for c in fit.illumination)
            print(f"  surface: {terms}")
    base, best = fits["flat light (main)"], fits["degree 4 + per-cell brightness + widths"]
    for name, fit in (("flat", base), ("best", best)):
        z = fit.residual.astype(float) / np.sqrt(_variance(fit))
        print(f"{name}: standardised residual power above 0.35 cycles/px {_white_power(z):.3f}")
        for region, (frac, chi2, share) in _regions(fit, z**2).items():
            print(f"  {region}: {frac:.3f} of pixels, chi-square {chi2:.1f}, share {share:.3f}")
    lo, hi = np.percentile(image, [0.5, 99.9])
    scale = float(np.percentile(np.abs(base.residual), 99.5))
    panels = [
        ("real", image, "gray", lo, hi),
        ("fit (flat light)", base.synthetic, "gray", lo, hi),
        (f"residual, chi2 {base.objective_after:.1f}", base.residual, "bwr", -scale, scale),
        ("fit (degree 4 + cells)", best.synthetic, "gray", lo, hi),
        (f"residual, chi2 {best.objective_after:.1f}", best.residual, "bwr", -scale, scale),
    ]
    fig, axes = plt.subplots(1, len(panels), figsize=(11, 9.5))
    for ax, (title, data, cmap, vmin, vmax) in zip(axes, panels):
        shown = ax.imshow(data, cmap=cmap, vmin=vmin, vmax=vmax, interpolation="nearest")
        ax.set_title(title, fontsize=10)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(shown, ax=axes, fraction=0.02, label="real - fit (ADU; red: fit too dark)")
    out = ROOT / "docs" / "images" / "fit_trench_residual.png"
    fig.savefig(out, dpi=90, bbox_inches="tight")
    print(f"wrote {out}")


if __name__ == "__main__":
    main(parse_real_data(__doc__, "ecoli_100x_oil_exponential.tiff"))
