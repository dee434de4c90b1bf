"""Figures and numbers of docs/rendering.md, "Phase contrast of dense colonies".

For each real phase-contrast colony of ``../shared/data/real/omnipose`` (8-bit, with
instance masks), fits the optics with the scene drawn from the masks
(:func:`napari_symbac.scene.scene_from_masks`) twice: the linear (weak-phase)
annulus kernel with separate phase amplitudes, and the partially coherent model; then,
on the partially coherent optics, each cell's own optical path
(:func:`napari_symbac.fit.cell_gains.fit_cell_gains`, as ``fit_colony`` does).
Writes

* ``docs/images/phase_colony_comparison.png``: real | fitted (partially coherent, each
  cell's own optical path) | residual, one row per image;
* ``docs/images/phase_profiles.png``: mean intensity against the signed distance to
  the cells' outline and to the colony's outline, real vs the fits;
* ``docs/images/phase_fit_numbers.json``: class medians, fitted values, timings;
* ``docs/images/phase_agar_pad.png`` (``python docs/scripts/make_phase_figures.py pad``,
  after the fits): simulated agar-pad colonies (three colonies, scattered cells) rendered
  with the optics fitted to Sample000193, beside that real colony, and their class
  medians (``phase_agar_pad_numbers.json``).

Run from the repository root: ``python docs/scripts/make_phase_figures.py`` (a few
minutes on 2 shared cores). The Omnipose images are MIT-licensed (their
LICENSE_MIT.txt).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import matplotlib
from _args import REAL_DATA, checked_real_data, script_parser

matplotlib.use("Agg")
import imageio.v3 as iio
import matplotlib.pyplot as plt
import numpy as np
import tifffile
from scipy import ndimage

from napari_symbac.fit import fit_parameters
from napari_symbac.fit.cell_gains import fit_cell_gains
from napari_symbac.fit.masks import (
    class_medians,
    distance_profile,
    estimate_pixel_size_um,
    normalise_percentiles,
)
from napari_symbac.optics import ForwardModel
from napari_symbac.scene import scene_from_masks
from napari_symbac.settings import Camera, Microscope, RenderSettings

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "images"
REAL = REAL_DATA / "omnipose"
SAMPLES = ("Sample000193", "Sample000033", "Sample000252")
WAVELENGTH_UM, NA = 0.55, 1.45  # not recorded with the images: a green-filtered 100x oil
CAMERA = Camera(baseline_adu=0.0, sensitivity_adu_per_e=1.0, dark_noise_e=0.0, bit_depth=8)
HALO_REACH_UM = 4.0  # scene border (PSF radius): the halo's reach
FAR_UM = 2.0  # "background": at least this far from every cell
CELL_EDGES_PX = np.arange(-7.0, 12.0)
LINEAR_FIT = ("apodisation_sigma_um", "phase_ring_width_scale")
COLONY_EDGES_UM = np.array([-6, -4, -3, -2, -1.5, -1, -0.5, 0, 0.5, 1, 1.5, 2, 3, 4, 6, 9])


def save(fig, path: Path) -> None:
    """Save a figure as a 256-colour PNG (a quarter of the bytes, same look)."""
    from PIL import Image

    fig.savefig(path, dpi=80)
    plt.close(fig)
    Image.open(path).convert("RGB").quantize(256).save(path, optimize=True)


def load(name: str) -> tuple[np.ndarray, np.ndarray]:
    image = iio.imread(REAL / f"{name}.png")
    image = image[..., 0] if image.ndim == 3 else image
    labels = tifffile.imread(REAL / f"{name}_cp_masks.tif").astype(np.int64)
    return image.astype(np.float64), labels


def colony_mask(labels: np.ndarray) -> np.ndarray:
    """The colonies' filled outline: cells closed over their gaps (5 px), holes filled."""
    return ndimage.binary_fill_holes(ndimage.binary_closing(labels > 0, iterations=5))


def settings(px: float, model: str) -> tuple[Microscope, RenderSettings]:
    # the partially coherent model needs the image band 2 NA / lambda sampled
    upsample = max(1, math.ceil(px / (WAVELENGTH_UM / (4 * NA))))
    microscope = Microscope(pixel_size_um=px, wavelength_um=WAVELENGTH_UM, numerical_aperture=NA)
    common = {
        "upsample": upsample,
        "psf_radius_px": math.ceil(HALO_REACH_UM / (px / upsample)),
        "cell_intensity": 80.0,
        "media_intensity": 80.0,
        "device_intensity": 80.0,
        "apodisation_sigma_um": 2.0,
        "noise_model": "gaussian",
    }
    if model == "partially_coherent":
        render = RenderSettings(
            **common, phase_model="partially_coherent", cell_phase_rad=0.8, plate_transmission=0.2
        )
    else:
        render = RenderSettings(**common, ring_model="annulus", cell_phase_adu=50.0)
    return microscope, render


def fit_one(image: np.ndarray, labels: np.ndarray, px: float, model: str) -> dict:
    microscope, render = settings(px, model)
    scene = scene_from_masks(labels, microscope, render)
    start = time.perf_counter()
    # partially coherent: its default (phase, apodisation, ring width); linear: the
    # kernel's shape (apodisation, ring width), its amplitudes solved exactly
    fit = None if model == "partially_coherent" else LINEAR_FIT
    result = fit_parameters(
        image, None, scene, microscope, render, CAMERA, terms=("pixel",), fit=fit,
        max_evaluations=80,
    )  # fmt: skip
    seconds = time.perf_counter() - start
    model_ = ForwardModel(microscope, result.render, CAMERA)
    clean = model_.render_clean(scene).astype(np.float64)
    noisy = model_.render(scene, np.random.default_rng(0)).astype(np.float64)
    far = FAR_UM / px
    return {
        "render": result.render,
        "clean": clean,
        "noisy": noisy,
        "seconds": seconds,
        "evaluations": result.n_evaluations,
        "warnings": list(result.warnings),
        "fitted": {n: float(getattr(result.render, n)) for n in result.fitted},
        "medians": class_medians(noisy, labels, far),
        "rms_adu": float(np.sqrt(np.mean((image - clean) ** 2))),
    }


def with_own_paths(image: np.ndarray, labels: np.ndarray, px: float, optics: dict) -> dict:
    """``optics`` (a partially coherent :func:`fit_one`) with each cell's optical path
    fitted on its optics (80 renders at most)."""
    microscope, _ = settings(px, "partially_coherent")
    render = optics["render"]
    scene = scene_from_masks(labels, microscope, render)
    start = time.perf_counter()
    fit = fit_cell_gains(image, scene, microscope, render, CAMERA, max_evaluations=80)
    seconds = time.perf_counter() - start
    model_ = ForwardModel(microscope, render, CAMERA)
    clean = fit.image
    noisy = model_.render(fit.scene, np.random.default_rng(0)).astype(np.float64)
    gains = np.array(list(fit.gains.values()))
    return {
        "render": render,
        "clean": clean,
        "noisy": noisy,
        "seconds": seconds,
        "evaluations": fit.n_evaluations,
        "warnings": list(fit.warnings),
        "fitted": {
            "cell_gain_cv": fit.cv,
            "cell_gain_quantiles_5_50_95": np.percentile(gains, [5, 50, 95]).tolist(),
        },
        "medians": class_medians(noisy, labels, FAR_UM / px),
        "rms_adu": float(np.sqrt(np.mean((image - clean) ** 2))),
    }


def profiles(image: np.ndarray, labels: np.ndarray, px: float) -> tuple[np.ndarray, np.ndarray]:
    norm = normalise_percentiles(image)
    cells = distance_profile(norm, labels > 0, CELL_EDGES_PX)
    colony = distance_profile(norm, colony_mask(labels), COLONY_EDGES_UM / px)
    return cells, colony


def main(names: tuple[str, ...] = SAMPLES) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    numbers, rows = {}, []
    for name in names:
        image, labels = load(name)
        px = estimate_pixel_size_um(labels)
        real_medians = class_medians(image, labels, FAR_UM / px)
        fits = {m: fit_one(image, labels, px, m) for m in ("partially_coherent", "linear")}
        fits["own_paths"] = with_own_paths(image, labels, px, fits["partially_coherent"])
        numbers[name] = {
            "shape": list(image.shape),
            "cells": int(labels.max()),
            "pixel_size_um": px,
            "real_medians": real_medians,
            **{
                m: {k: v for k, v in f.items() if k not in ("render", "clean", "noisy")}
                for m, f in fits.items()
            },
        }
        print(name, json.dumps(numbers[name], indent=1), flush=True)
        rows.append((name, image, labels, px, fits))
    (OUT / "phase_fit_numbers.json").write_text(json.dumps(numbers, indent=1))

    fig, axes = plt.subplots(len(rows), 3, figsize=(11, 3.7 * len(rows)))
    axes = np.atleast_2d(axes)
    for (name, image, labels, _px, fits), ax in zip(rows, axes):
        fitted = fits["own_paths"]["noisy"]
        low, high = np.percentile(image, [1, 99])
        residual = image - fits["own_paths"]["clean"]
        limit = np.percentile(np.abs(residual), 99)
        panels = (
            (image, "gray", (low, high), f"{name}: real, {int(labels.max())} cells"),
            (fitted, "gray", (low, high), "fitted, partially coherent, own paths (+ noise)"),
            (residual, "RdBu_r", (-limit, limit), "residual real - fitted (noise-free)"),
        )
        for a, (img, cmap, (vmin, vmax), title) in zip(ax, panels):
            a.imshow(img, cmap=cmap, vmin=vmin, vmax=vmax)
            a.set_title(title, fontsize=9, loc="left")
            a.set_xticks([])
            a.set_yticks([])
    fig.tight_layout()
    save(fig, OUT / "phase_colony_comparison.png")

    fig, axes = plt.subplots(len(rows), 2, figsize=(10, 3.2 * len(rows)))
    axes = np.atleast_2d(axes)
    cell_x = CELL_EDGES_PX[:-1] + 0.5
    for (name, image, labels, px, fits), (a, b) in zip(rows, axes):
        colony_x = 0.5 * (COLONY_EDGES_UM[:-1] + COLONY_EDGES_UM[1:])
        for label, img, style in (
            ("real", image, "k-"),
            ("partially coherent, each cell's own path", fits["own_paths"]["noisy"], "C2-"),
            ("partially coherent fit", fits["partially_coherent"]["noisy"], "C3-"),
            ("linear (weak-phase) fit", fits["linear"]["noisy"], "C0--"),
        ):
            cells, colony = profiles(img, labels, px)
            a.plot(cell_x * px, cells, style, label=label)
            b.plot(colony_x, colony, style, label=label)
        a.set_title(f"{name}: across cell edges (gaps count as outside)", fontsize=9, loc="left")
        b.set_title(f"{name}: across the colony edge", fontsize=9, loc="left")
        for ax_ in (a, b):
            ax_.axvline(0, color="0.7", lw=0.8)
            ax_.set_xlabel("signed distance to the outline (um), negative inside")
            ax_.set_ylabel("normalised intensity (1-99 %)")
        a.legend(fontsize=8)
    fig.tight_layout()
    save(fig, OUT / "phase_profiles.png")


def synthetic_pad() -> None:
    """Simulated colonies rendered with the optics fitted to Sample000193."""
    from napari_symbac.pipeline import draw_frame, noise_rng
    from napari_symbac.settings import AgarPadGeometry, PipelineSettings, SimulationSettings
    from napari_symbac.sim import simulate

    numbers = json.loads((OUT / "phase_fit_numbers.json").read_text())["Sample000193"]
    px = numbers["pixel_size_um"]
    microscope, render = settings(px, "partially_coherent")
    fitted = numbers["partially_coherent"]["fitted"]
    render = RenderSettings(
        **{**render.__dict__, **fitted, "gaussian_noise_sd_adu": 1.2, "media_intensity": 76.0,
           "cell_intensity": 76.0, "device_intensity": 76.0},
    )  # fmt: skip
    simulation = simulate(
        SimulationSettings(
            geometry="agar_pad",
            n_frames=40,
            n_founders=6,
            gravity=8.0,
            agar_pad=AgarPadGeometry(
                40.0, 40.0, n_colonies=3, scattered_cells=4, colony_separation_um=14.0
            ),
            seed=4,
        )
    )
    pipeline = PipelineSettings(
        simulation=simulation.settings, microscope=microscope, render=render, camera=CAMERA
    )
    scene = draw_frame(simulation, pipeline, len(simulation.frames) - 1)
    image = ForwardModel(microscope, render, CAMERA).render(scene, noise_rng(pipeline))
    labels = scene.camera_labels().astype(np.int64)
    real, real_labels = load("Sample000193")
    medians = {
        "synthetic": class_medians(image.astype(np.float64), labels, FAR_UM / px),
        "real Sample000193": class_medians(real, real_labels, FAR_UM / px),
        "cells": int(len(np.unique(labels)) - 1),
    }
    (OUT / "phase_agar_pad_numbers.json").write_text(json.dumps(medians, indent=1))
    print(json.dumps(medians, indent=1))
    fig, axes = plt.subplots(1, 2, figsize=(11, 5.6))
    for ax, img, title in (
        (axes[0], real, "real: Sample000193 (Omnipose, MIT)"),
        (axes[1], image, f"simulated: 3 colonies + 4 scattered cells, {medians['cells']} cells"),
    ):
        low, high = np.percentile(img, [1, 99])
        ax.imshow(img, cmap="gray", vmin=low, vmax=high)
        ax.set_title(title, fontsize=9, loc="left")
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    save(fig, OUT / "phase_agar_pad.png")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line: ``[pad | NAME ...]``; the colonies are read from REAL."""
    parser = script_parser(__doc__)
    parser.add_argument(
        "names",
        nargs="*",
        metavar="pad | NAME",
        help="'pad': the agar-pad figure (after the fits); else the Omnipose colonies to "
        f"fit (default: {' '.join(SAMPLES)})",
    )
    args = parser.parse_args(argv)
    checked_real_data(parser, REAL, "the Omnipose colonies", given="repository")
    return args


if __name__ == "__main__":
    names = parse_args().names
    if names == ["pad"]:
        synthetic_pad()
    else:
        main(tuple(names) or SAMPLES)
