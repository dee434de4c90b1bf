"""Render rows: the trench frame's per-frame path, the cached re-render, field drawing.

The trench: 256 x 46 camera px, 5 cells, 3x upsampling, a radius-50 PSF (render frame
868 x 238). Steps are timed interleaved (one of each in turn, medians of the rounds)
in CPU time of the calling thread (``time.thread_time``; every step timed is
single-threaded), which a shared, loaded machine disturbs less than wall time, each
beside the FFT floor (:func:`~napari_symbac.bench.timing.fft_floor`) of the same frame
timed in the same rounds. Issue 15's goals: the full per-frame path (draw + fast render
with noise + masks) <= 1.5 x the floor; drawing + masks of a 1024 x 1024 field of 360
cells and a 2048 x 2048 field of 1440 cells <= 0.3 x the floor. The drawing and the
masks are compiled (numba): their first call in a process is paid before the rounds.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from types import SimpleNamespace

import numpy as np

from napari_symbac.bench.config import BenchConfig
from napari_symbac.bench.registry import register
from napari_symbac.bench.timing import fft_floor

__all__ = [
    "FIELD_CASES",
    "TRENCH_256",
    "colony_cells",
    "field_draw_1024",
    "field_draw_2048",
    "measure_cached_paths",
    "measure_field_draw",
    "measure_trench_frame",
    "render_trench",
    "trench_cells",
    "trench_settings",
]

#: The 256 x 46 camera-px trench of docs/benchmarks.md.
TRENCH_256 = {"length_um": 15.84, "width_um": 1.4, "margin_um": 0.8}
#: Field sizes (camera px) and cell counts of issue 15's drawing goal.
FIELD_CASES = ((1024, 360), (2048, 1440))


def trench_cells(shift_um: float) -> SimpleNamespace:
    """Five 3.1 um cells down the trench, shifted by ``shift_um`` (a new frame)."""
    y = np.array([1.7, 5.0, 8.3, 11.6, 14.9]) + shift_um
    n = y.size
    return SimpleNamespace(
        ids=np.arange(1, n + 1),
        x_um=np.full(n, 0.7),
        y_um=y,
        angle_rad=np.zeros(n),
        length_um=np.full(n, 3.1),
        width_um=np.full(n, 1.0),
    )


def trench_settings(psf_radius_px: int = 50):
    """The benchmark's trench: ``(Microscope, RenderSettings, TrenchGeometry, Camera)``,
    256 x 46 camera px, upsample 3, PSF radius ``psf_radius_px``."""
    from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry

    return (
        Microscope(),
        RenderSettings(upsample=3, psf_radius_px=psf_radius_px),
        TrenchGeometry(**TRENCH_256),
        Camera(),
    )


def _cpu_time(times: list[float], fn: Callable, *args: object, **kwargs: object) -> object:
    """Call ``fn(*args, **kwargs)``, append its CPU time (this thread) to ``times``."""
    t0 = time.thread_time()
    result = fn(*args, **kwargs)
    times.append(time.thread_time() - t0)
    return result


def _masks(scene) -> tuple[np.ndarray, np.ndarray]:
    return scene.camera_labels(), scene.semantic_mask()


def measure_trench_frame(rounds: int = 30, psf_radius_px: int = 50) -> dict:
    """Per-frame cost of the 256 x 46 trench frame against the FFT floor.

    Each round times, in turn, on frames not seen before: ``draw_scene``; the fast
    render (``cache=False``) split into the noise-free image and the camera noise;
    the masks (``camera_labels`` + ``semantic_mask``); the full per-frame path of
    ``pipeline.iter_render`` (draw + fast render + masks) on another new frame; and
    one FFT convolution of the render frame. Times are medians over the rounds, in
    seconds of CPU time.

    Returns
    -------
    dict
        ``camera_shape``, ``render_shape``, ``rounds``, ``draw_s``, ``clean_s``,
        ``noise_s``, ``render_s`` (clean + noise), ``masks_s``, ``frame_s``,
        ``fft_floor_s`` and ``frame_over_floor``.
    """
    from napari_symbac.optics import ForwardModel
    from napari_symbac.scene import draw_scene

    microscope, render, trench, camera = trench_settings(psf_radius_px)
    model = ForwardModel(microscope, render, camera)
    rng = np.random.default_rng(0)
    scene = draw_scene(trench_cells(0.0), trench, microscope, render)
    model.render(scene, rng, cache=False)  # builds the kernel and its spectrum once
    _masks(scene)  # the compiled mask kernel's first call (once per process)
    floor = fft_floor(scene.cells, model.kernel())
    times: dict[str, list[float]] = {
        k: [] for k in ("draw", "clean", "noise", "masks", "frame", "floor")
    }

    def full_frame(cells: SimpleNamespace) -> tuple:
        frame_scene = draw_scene(cells, trench, microscope, render)
        image = model.render(frame_scene, rng, cache=False)
        return image, frame_scene.camera_labels(), frame_scene.semantic_mask()

    for k in range(rounds):
        cells = trench_cells(0.004 * k)
        new = _cpu_time(times["draw"], draw_scene, cells, trench, microscope, render)
        clean = _cpu_time(times["clean"], model.render_clean, new, cache=False)
        _cpu_time(times["noise"], model.add_noise, clean, rng)
        _cpu_time(times["masks"], _masks, new)
        _cpu_time(times["frame"], full_frame, trench_cells(0.004 * k + 0.002))
        _cpu_time(times["floor"], floor)
    med = {k: float(np.median(v)) for k, v in times.items()}
    return {
        "camera_shape": scene.camera_shape,
        "render_shape": scene.shape,
        "rounds": rounds,
        "draw_s": med["draw"],
        "clean_s": med["clean"],
        "noise_s": med["noise"],
        "render_s": med["clean"] + med["noise"],
        "masks_s": med["masks"],
        "frame_s": med["frame"],
        "fft_floor_s": med["floor"],
        "frame_over_floor": med["frame"] / med["floor"],
    }


def measure_cached_paths(rounds: int = 30) -> dict:
    """Cold render on the cached path and the cached re-render of the trench frame.

    Returns ``cold_cached_s`` (a new frame: the changed components convolved and
    cached, + noise), ``rerender_s`` (an intensity changed: recombine + noise),
    ``rfft2_s`` (one forward transform of the render frame), ``rerender_over_rfft2``
    and ``fft_floor_s``; medians, seconds of CPU time, interleaved.
    """
    from scipy import fft as sp_fft

    from napari_symbac.optics import ForwardModel
    from napari_symbac.scene import draw_scene

    microscope, render, trench, camera = trench_settings()
    model = ForwardModel(microscope, render, camera)
    rng = np.random.default_rng(0)
    scene = draw_scene(trench_cells(0.0), trench, microscope, render)
    model.render(scene, rng)
    scenes = [draw_scene(trench_cells(0.01 * k), trench, microscope, render) for k in range(rounds)]
    settings = [dataclasses.replace(render, cell_intensity=1000.0 + k) for k in range(rounds)]
    frame = np.asarray(scene.cells, np.float32)
    floor = fft_floor(frame, model.kernel())
    times: dict[str, list[float]] = {"cold": [], "cached": [], "rfft2": [], "floor": []}
    for k in range(rounds):
        _cpu_time(times["cold"], model.render, scenes[k], rng)
        _cpu_time(times["cached"], model.with_render(settings[k]).render, scene, rng)
        _cpu_time(times["rfft2"], sp_fft.rfft2, frame)
        _cpu_time(times["floor"], floor)
    med = {k: float(np.median(v)) for k, v in times.items()}
    return {
        "cold_cached_s": med["cold"],
        "rerender_s": med["cached"],
        "rfft2_s": med["rfft2"],
        "rerender_over_rfft2": med["cached"] / med["rfft2"],
        "fft_floor_s": med["floor"],
    }


def colony_cells(
    size_px: int, n_cells: int, seed: int = 0, pixel_um: float = 0.065
) -> tuple[SimpleNamespace, dict[int, tuple[float, float, float]], float]:
    """A colony-like field: ``n_cells`` cells on a jittered grid over the square field.

    Random orientations, lengths 2.0-3.6 um (at most 95% of the grid pitch), widths
    0.85-1.05 um, every fifth cell bent (eq. 1, ``a = 0.1`` um): about a fifth of the
    field is cell at 360 cells on 1024 x 1024 px. Returns the cells, the curvature
    mapping and the field's side in um.
    """
    rng = np.random.default_rng(seed)
    side_um = size_px * pixel_um
    k = int(np.ceil(np.sqrt(n_cells)))
    pitch = side_um / k
    if 0.95 * pitch <= 2.0:
        raise ValueError(
            f"{n_cells} cells do not fit a {size_px} px field as 2-3.6 um cells (grid pitch "
            f"{pitch:.2f} um): use fewer cells or a larger field"
        )
    slots = rng.permutation(k * k)[:n_cells]
    length = rng.uniform(2.0, min(3.6, 0.95 * pitch), n_cells)
    cells = SimpleNamespace(
        ids=np.arange(1, n_cells + 1),
        x_um=(slots % k + 0.5) * pitch + rng.uniform(-0.2, 0.2, n_cells),
        y_um=(slots // k + 0.5) * pitch + rng.uniform(-0.2, 0.2, n_cells),
        angle_rad=rng.uniform(0.0, np.pi, n_cells),
        length_um=length,
        width_um=rng.uniform(0.85, 1.05, n_cells),
    )
    curvature = {int(i): (0.1, 1.0, 0.0) for i in cells.ids[::5]}
    return cells, curvature, side_um


def measure_field_draw(size_px: int, n_cells: int, rounds: int = 5) -> dict:
    """Drawing a field of ``size_px x size_px`` camera px with ``n_cells`` cells.

    Each round times ``draw_scene`` (cells and labels at 3x upsampling, 50 px
    border; the device image is the geometry's cached one), then the masks of that
    new scene (``camera_labels`` + ``semantic_mask``), then its first read of
    ``media`` (made on first access, so paid by whoever reads it: the renderer), then
    one FFT convolution of its render frame. Medians over the rounds, seconds of CPU
    time. A draw and its masks before the rounds pay the compiled kernels' first call
    (numba loads or compiles them once per process; docs/rendering.md gives the cost).

    Returns
    -------
    dict
        ``size_px``, ``n_cells``, ``render_shape``, ``rounds``, ``draw_s``,
        ``masks_s``, ``draw_masks_s``, ``media_s``, ``fft_floor_s`` and
        ``draw_masks_over_floor``.
    """
    from napari_symbac.optics import ForwardModel
    from napari_symbac.scene import Field, draw_scene
    from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry

    microscope = Microscope()
    render = RenderSettings(upsample=3, psf_radius_px=50)
    cells, curvature, side_um = colony_cells(size_px, n_cells, pixel_um=microscope.pixel_size_um)
    field = Field(side_um, side_um)
    trench = TrenchGeometry()

    def draw():
        return draw_scene(cells, trench, microscope, render, curvature, field=field)

    scene = draw()
    _masks(scene)
    kernel = ForwardModel(microscope, render, Camera()).kernel()
    floor = fft_floor(scene.cells, kernel)
    render_shape = scene.shape
    del scene
    times: dict[str, list[float]] = {"draw": [], "masks": [], "media": [], "floor": []}
    for _ in range(rounds):
        new = _cpu_time(times["draw"], draw)
        _cpu_time(times["masks"], _masks, new)
        _cpu_time(times["media"], getattr, new, "media")
        del new
        _cpu_time(times["floor"], floor)
    med = {k: float(np.median(v)) for k, v in times.items()}
    both = med["draw"] + med["masks"]
    return {
        "size_px": size_px,
        "n_cells": n_cells,
        "render_shape": render_shape,
        "rounds": rounds,
        "draw_s": med["draw"],
        "masks_s": med["masks"],
        "draw_masks_s": both,
        "media_s": med["media"],
        "fft_floor_s": med["floor"],
        "draw_masks_over_floor": both / med["floor"],
    }


def _numbers(result: dict) -> dict[str, float]:
    """The float entries of ``result``, with ``fft_floor_s`` as the rows' ``fft_s``."""
    out = {k: float(v) for k, v in result.items() if isinstance(v, (int, float))}
    out["fft_s"] = out.pop("fft_floor_s")
    return out


@register("render_trench")
def render_trench(config: BenchConfig) -> dict[str, float]:
    """:func:`measure_trench_frame` (``fft_s``: its floor) and the cached re-render
    (``cached_s``) of :func:`measure_cached_paths`."""
    rounds = max(5, config.render_frames)
    out = _numbers(measure_trench_frame(rounds))
    out["cached_s"] = measure_cached_paths(rounds)["rerender_s"]
    return out


def _field_draw(config: BenchConfig, index: int) -> dict[str, float]:
    size_px, n_cells = FIELD_CASES[index]
    return _numbers(measure_field_draw(size_px, n_cells, rounds=3 if config.quick else 5))


@register("field_draw_1024")
def field_draw_1024(config: BenchConfig) -> dict[str, float]:
    """Draw + masks of the 1024 x 1024 field of 360 cells (:func:`measure_field_draw`)."""
    return _field_draw(config, 0)


@register("field_draw_2048")
def field_draw_2048(config: BenchConfig) -> dict[str, float]:
    """Draw + masks of the 2048 x 2048 field of 1440 cells (not run with ``--quick``)."""
    from napari_symbac.bench.subprocesses import BenchSkipped

    if config.quick:
        raise BenchSkipped("not run with --quick")
    return _field_draw(config, 1)
