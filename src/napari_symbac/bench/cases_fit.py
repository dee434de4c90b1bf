"""Fit rows: ``fit_scene`` on a rendered trench and on a fluorescence open field.

The images are rendered from known cells, so the fit has a truth to find; the row is its
wall time. ``config.fit_iterations`` caps the iterations (``--quick``: a few, no moves).
"""

from __future__ import annotations

import time

import numpy as np

from napari_symbac.bench.config import BenchConfig
from napari_symbac.bench.registry import register
from napari_symbac.bench.timing import fft_floor_s

__all__ = ["fit_field", "fit_trench"]

_PIXEL_UM = 0.065


def _trench_cells():
    from napari_symbac.sim import FrameCells

    y = np.array([1.3, 3.9, 6.5, 9.0, 11.6, 14.2])
    n = y.size
    return FrameCells(
        ids=np.arange(1, n + 1),
        x_um=np.full(n, 0.75) + 0.02 * np.sin(np.arange(n)),
        y_um=y,
        angle_rad=0.05 * np.cos(np.arange(n)),
        length_um=np.array([2.3, 2.6, 2.2, 2.4, 2.5, 2.3]),
        width_um=np.full(n, 0.95),
    )


def _fit(image, microscope, start, config: BenchConfig, **kwargs) -> float:
    from napari_symbac.fit import fit_scene

    t0 = time.perf_counter()
    fit_scene(
        image,
        microscope,
        start,
        None,
        max_iterations=config.fit_iterations,
        moves=not config.quick,
        irls_rounds=1 if config.quick else 3,
        **kwargs,
    )
    return time.perf_counter() - t0


@register("fit_trench")
def fit_trench(config: BenchConfig) -> dict[str, float]:
    """``fit_scene`` of a 256 x 46 phase trench of 6 cells: ``fit_s``, ``fft_s``."""
    from napari_symbac.optics import ForwardModel
    from napari_symbac.scene import draw_scene
    from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry

    microscope = Microscope(pixel_size_um=_PIXEL_UM)
    trench = TrenchGeometry(length_um=256 * _PIXEL_UM - 0.75, width_um=1.5, margin_um=0.75)
    truth = RenderSettings(apodisation_sigma_um=0.6, defocus_sigma_um=0.15, psf_offset=0.05)
    scene = draw_scene(_trench_cells(), trench, microscope, truth)
    model = ForwardModel(microscope, truth, Camera())
    image = model.render(scene, np.random.default_rng(0))
    start = RenderSettings(cell_intensity=1700.0, media_intensity=2100.0)
    return {
        "fit_s": _fit(image, microscope, start, config),
        "fft_s": fft_floor_s(scene.shape, np.asarray(model.kernel(), np.float32)),
    }


@register("fit_field")
def fit_field(config: BenchConfig) -> dict[str, float]:
    """``fit_scene`` of a 256 x 256 fluorescence open field (16 cells; 4 with --quick)."""
    from napari_symbac.bench.cases_render import field_cells
    from napari_symbac.optics import ForwardModel
    from napari_symbac.scene import Field, draw_scene
    from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry

    side, count, px = 256, 4 if config.quick else 16, 0.08
    microscope = Microscope(pixel_size_um=px, modality="fluorescence")
    render = RenderSettings(cell_intensity=2000.0, media_intensity=150.0, defocus_sigma_um=0.1)
    cells = field_cells(side, count, px, np.random.default_rng(count))
    field = Field(side * px, side * px)
    scene = draw_scene(cells, TrenchGeometry(), microscope, render, field=field)
    model = ForwardModel(microscope, render, Camera())
    image = model.render(scene, np.random.default_rng(0))
    return {
        "fit_s": _fit(image, microscope, RenderSettings(), config, geometry="open"),
        "fft_s": fft_floor_s(scene.shape, np.asarray(model.kernel(), np.float32)),
        "cells": float(count),
    }
