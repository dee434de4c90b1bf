"""Fit rows: ``fit_scene`` on a rendered 256 x 46 trench and on fluorescence open fields.

The images are rendered from known cells, so the fit has a truth to find; the rows are
its wall time, beside the FFT floor of the render frame. ``--quick`` caps the fit
(``config.fit_iterations`` iterations, one IRLS round, no cell moves).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from napari_symbac.bench.config import BenchConfig
from napari_symbac.bench.registry import register
from napari_symbac.bench.timing import fft_floor, fft_floor_s

__all__ = [
    "PIXEL_UM",
    "START",
    "TRENCH",
    "TRUTH",
    "field_image",
    "fit_field",
    "fit_trench",
    "measure_fit_field",
    "measure_fit_parameters",
    "measure_fit_trench",
]

PIXEL_UM = 0.065


def _settings():
    from napari_symbac.settings import RenderSettings, TrenchGeometry

    trench = TrenchGeometry(length_um=256 * PIXEL_UM - 0.75, width_um=1.5, margin_um=0.75)
    truth = RenderSettings(apodisation_sigma_um=0.6, defocus_sigma_um=0.15, psf_offset=0.05)
    start = RenderSettings(
        cell_intensity=1700.0,
        media_intensity=2100.0,
        apodisation_sigma_um=1.0,
        defocus_sigma_um=0.05,
        psf_offset=0.0,
    )
    return trench, truth, start


TRENCH, TRUTH, START = _settings()


def _cells():
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


def _best_of(func, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        func()
        times.append(time.perf_counter() - start)
    return min(times)


def _trench_image():
    from napari_symbac.optics import ForwardModel
    from napari_symbac.scene import draw_scene
    from napari_symbac.settings import Camera, Microscope

    microscope, camera = Microscope(pixel_size_um=PIXEL_UM), Camera()
    scene = draw_scene(_cells(), TRENCH, microscope, TRUTH)
    model = ForwardModel(microscope, TRUTH, camera)
    return microscope, camera, scene, model, model.render(scene, np.random.default_rng(0))


def measure_fit_trench(real_trench: np.ndarray | None = None, **fit_kwargs: Any) -> dict:
    """``fit_scene`` on the synthetic 256 x 46 trench (camera given) and, when
    ``real_trench`` is given, on that real 100x trench (round closed end, camera
    estimated). ``fit_kwargs`` go to both fits (e.g. ``max_iterations``).

    Returns
    -------
    dict
        ``render_shape``, ``synthetic_s``, ``synthetic_chi2``, ``synthetic_renders``,
        ``synthetic_cells`` and, with the real trench, ``real_s``, ``real_chi2``,
        ``real_renders``, ``real_cells`` (seconds of wall time, reduced chi-square,
        renders and patches, fitted cells).
    """
    from napari_symbac.fit import fit_scene
    from napari_symbac.settings import RenderSettings

    microscope, camera, scene, _, image = _trench_image()
    start = time.perf_counter()
    fitted = fit_scene(image, microscope, START, camera, **fit_kwargs)
    out: dict[str, Any] = {
        "render_shape": scene.shape,
        "synthetic_s": time.perf_counter() - start,
        "synthetic_chi2": float(fitted.objective_after),
        "synthetic_renders": int(fitted.n_evaluations),
        "synthetic_cells": len(fitted.cells),
    }
    if real_trench is not None:
        start = time.perf_counter()
        fitted = fit_scene(
            real_trench, microscope, RenderSettings(), None, closed_end="round", **fit_kwargs
        )
        out.update(
            real_s=time.perf_counter() - start,
            real_chi2=float(fitted.objective_after),
            real_renders=int(fitted.n_evaluations),
            real_cells=len(fitted.cells),
        )
    return out


def field_image(side: int, count: int):
    """``count`` cells on a jittered grid of an open ``side`` x ``side`` fluorescence
    field (80 nm px), rendered: ``(image, render_shape)``."""
    from napari_symbac.optics import ForwardModel
    from napari_symbac.scene import Field, draw_scene
    from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry
    from napari_symbac.sim import FrameCells

    rng = np.random.default_rng(count)
    per_row = int(np.ceil(np.sqrt(count)))
    pitch = side * 0.08 / per_row
    ix, iy = np.meshgrid(np.arange(per_row), np.arange(per_row))
    x = ((ix.ravel() + 0.5) * pitch)[:count] + rng.uniform(-0.2, 0.2, count)
    y = ((iy.ravel() + 0.5) * pitch)[:count] + rng.uniform(-0.2, 0.2, count)
    length = np.minimum(rng.uniform(1.8, 3.0, count), pitch - 0.9)
    cells = FrameCells(
        ids=np.arange(1, count + 1),
        x_um=x,
        y_um=y,
        angle_rad=rng.uniform(-1.5, 1.5, count),
        length_um=np.maximum(length, 1.0),
        width_um=np.full(count, 0.9),
    )
    microscope = Microscope(pixel_size_um=0.08, modality="fluorescence")
    render = RenderSettings(cell_intensity=2000.0, media_intensity=150.0, defocus_sigma_um=0.1)
    field = Field(side * 0.08, side * 0.08)
    scene = draw_scene(cells, TrenchGeometry(), microscope, render, field=field)
    image = ForwardModel(microscope, render, Camera()).render(scene, np.random.default_rng(0))
    return image, scene.shape


def measure_fit_field(side: int = 256, count: int = 36, **fit_kwargs: Any) -> dict:
    """``fit_scene`` on an open fluorescence field of ``count`` cells (camera estimated).

    Returns
    -------
    dict
        ``side`` (pixels), ``cells`` (truth), ``found``, ``seconds`` (wall), ``chi2``
        (reduced chi-square), ``renders`` (renders and patches), ``render_shape``.
    """
    from napari_symbac.fit import fit_scene
    from napari_symbac.settings import Microscope, RenderSettings

    image, shape = field_image(side, count)
    start = time.perf_counter()
    fitted = fit_scene(
        image,
        Microscope(pixel_size_um=0.08, modality="fluorescence"),
        RenderSettings(),
        None,
        geometry="open",
        **fit_kwargs,
    )
    return {
        "side": side,
        "cells": count,
        "found": len(fitted.cells),
        "seconds": time.perf_counter() - start,
        "chi2": float(fitted.objective_after),
        "renders": int(fitted.n_evaluations),
        "render_shape": shape,
    }


def measure_fit_parameters() -> dict:
    """``fit_parameters`` on the synthetic trench: the FFT floor and both terms.

    Returns
    -------
    dict
        ``fft_s`` (:func:`~napari_symbac.bench.timing.fft_floor` of the render frame,
        best of 20), ``pixel_s``, ``pixel_renders``, ``statistics_s``,
        ``statistics_renders``.
    """
    from napari_symbac.fit import fit_parameters, scene_classes

    microscope, camera, scene, model, image = _trench_image()
    out = {"fft_s": _best_of(fft_floor(scene.cells, model.kernel()), 20)}
    classes = scene_classes(scene)
    for name, kwargs in (("pixel", {"terms": ("pixel",)}), ("statistics", {})):
        start = time.perf_counter()
        result = fit_parameters(image, classes, scene, microscope, START, camera, **kwargs)
        out[f"{name}_s"] = time.perf_counter() - start
        out[f"{name}_renders"] = int(result.n_evaluations)
    return out


def _fit_kwargs(config: BenchConfig) -> dict[str, Any]:
    """``fit_scene``'s defaults, or a capped fit with ``--quick``."""
    if not config.quick:
        return {"max_iterations": config.fit_iterations}
    return {"max_iterations": config.fit_iterations, "moves": False, "irls_rounds": 1}


@register("fit_trench")
def fit_trench(config: BenchConfig) -> dict[str, float]:
    """:func:`measure_fit_trench` of the synthetic trench: ``fit_s``, ``fft_s``."""
    run = measure_fit_trench(**_fit_kwargs(config))
    return {"fit_s": run["synthetic_s"], "fft_s": fft_floor_s(run["render_shape"])}


@register("fit_field")
def fit_field(config: BenchConfig) -> dict[str, float]:
    """:func:`measure_fit_field` of a 256 x 256 field of ``config.fit_field_cells``."""
    run = measure_fit_field(256, config.fit_field_cells, **_fit_kwargs(config))
    return {
        "fit_s": run["seconds"],
        "fft_s": fft_floor_s(run["render_shape"]),
        "cells": float(run["cells"]),
    }
