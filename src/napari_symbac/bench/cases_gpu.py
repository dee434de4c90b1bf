"""GPU / batched rows: the device renderer against the scipy path, frames/s.

Times the render stage alone (scene components in, uint16 camera images out, noise
included; drawing the scenes is not timed, it is the same for both paths):

* scipy: :meth:`ForwardModel.render` (``cache=False``, the fused convolution + block
  average) frame by frame, as ``napari-symbac render --backend scipy`` does;
* torch: :class:`~napari_symbac.optics.batched.BatchedRenderer` on ``torch:cpu`` and,
  where torch sees a GPU, ``torch:cuda`` (frames batched and kept on the device).

Frames: a 256 x 46 camera-pixel trench frame (5 cells, 3x upsampling, PSF radius 50,
the project's defaults) and a square open field (``1024 x 1024`` camera pixels) of
cell-like blobs. Each batch cycles through a few distinct scenes (the render cost does
not depend on the content). :func:`compare` interleaves the backends and repeats.
"""

from __future__ import annotations

import statistics
import time
from functools import lru_cache
from typing import Any

import numpy as np

from napari_symbac.bench.cases_render import trench_cells
from napari_symbac.bench.config import BenchConfig
from napari_symbac.bench.registry import register
from napari_symbac.bench.subprocesses import BenchSkipped
from napari_symbac.bench.timing import fft_floor_s
from napari_symbac.optics import ForwardModel
from napari_symbac.optics.batched import BatchedRenderer, resolve_backend
from napari_symbac.scene import Scene, draw_scene
from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry

__all__ = [
    "FIELD",
    "TRENCH",
    "available",
    "batch_cpu_trench",
    "compare",
    "gpu_field_1024",
    "gpu_trench",
    "measure_batch",
    "scenes_for",
]

TRENCH = (256, 46)
FIELD = (1024, 1024)
MICROSCOPE = Microscope()
RENDER = RenderSettings()  # psf radius 50, upsample 3, camera noise
CAMERA = Camera()


def _field_scene(shape: tuple[int, int], seed: int) -> Scene:
    """An open field of ``shape`` camera px: soft blobs of cells in media, no device."""
    from scipy.ndimage import gaussian_filter

    up, border = RENDER.upsample, RENDER.psf_radius_px
    rows, cols = shape[0] * up + 2 * border, shape[1] * up + 2 * border
    rng = np.random.default_rng(seed)
    seeds = np.zeros((rows, cols), np.float32)
    n_cells = max(1, rows * cols // 4000)
    seeds[rng.integers(0, rows, n_cells), rng.integers(0, cols, n_cells)] = 1.0
    cells = np.clip(gaussian_filter(seeds, 6.0) * 900.0, 0.0, 1.0).astype(np.float32)
    labels = (cells > 0.5).astype(np.uint32)
    return Scene(
        cells=cells,
        media=(1.0 - cells).astype(np.float32),
        device=np.zeros_like(cells),
        labels=labels,
        border_px=border,
        upsample=up,
        camera_shape=shape,
        pixel_size_um=MICROSCOPE.pixel_size_um / up,
        depth_um=1.0,
    )


@lru_cache(maxsize=4)
def scenes_for(shape: tuple[int, int], distinct: int = 4) -> tuple[Scene, ...]:
    """``distinct`` scenes of ``shape`` camera px: trench frames for ``(256, 46)``, else fields."""
    if tuple(shape) == TRENCH:
        geometry = TrenchGeometry()
        return tuple(
            draw_scene(trench_cells(0.3 * k), geometry, MICROSCOPE, RENDER)
            for k in range(distinct)
        )
    return tuple(_field_scene(tuple(shape), seed) for seed in range(distinct))


def available() -> list[tuple[str, int | None]]:
    """``(backend, threads)`` runs measurable here: scipy; torch:cpu on one thread (like
    scipy's FFT) and on torch's default threads; torch:cuda where torch sees a GPU."""
    runs: list[tuple[str, int | None]] = [("scipy", None)]
    try:
        cuda = resolve_backend("torch") == "torch:cuda"
    except ValueError:  # no torch
        return runs
    runs += [("torch:cpu", 1), ("torch:cpu", None)]
    if cuda:
        runs.append(("torch:cuda", None))
    return runs


def _sync(backend: str) -> None:
    if backend.startswith("torch:cuda"):
        import torch

        torch.cuda.synchronize()


def measure_batch(
    backend: str,
    n_frames: int,
    shape: tuple[int, int] = TRENCH,
    *,
    threads: int | None = None,
    seed: int = 0,
) -> dict[str, Any]:
    """Render ``n_frames`` frames of ``shape`` camera px on ``backend`` once; time it.

    Parameters
    ----------
    backend
        ``"scipy"``, ``"torch:cpu"``, ``"torch:cuda"`` (or ``"torch"``: cuda when
        available).
    n_frames
        Frames in the batch (the torch path splits it into device batches by memory).
    shape
        Camera pixels of a frame; ``(256, 46)`` is a trench frame, any other shape an
        open field.
    threads
        ``torch:cpu`` only: torch's intra-op threads during the run (``None``: torch's
        default, one per core). scipy's FFT runs one thread, as the project calls it.

    Returns
    -------
    dict
        ``backend`` (resolved), ``threads``, ``n_frames``, ``shape``, ``seconds`` (wall time of the
        batch, scenes drawn beforehand), ``frames_per_s`` and ``mpx_per_s`` (camera
        megapixels per second). A first small batch warms the device up (kernel
        spectrum, allocator) and is not timed.
    """
    name = resolve_backend(backend)
    pool = scenes_for(tuple(shape))
    scenes = [pool[i % len(pool)] for i in range(n_frames)]
    model = ForwardModel(MICROSCOPE, RENDER, CAMERA)
    rng = np.random.default_rng(seed)
    if name == "scipy":

        def run() -> None:
            for scene in scenes:
                model.render(scene, rng, cache=False)

        model.render(scenes[0], rng, cache=False)  # warm-up: kernel and its spectrum
    else:
        renderer = BatchedRenderer(model, name.partition(":")[2])

        def run() -> None:
            renderer.render(scenes, rng)

        renderer.render(scenes[: min(2, n_frames)], rng)
    previous = None
    if name == "torch:cpu" and threads is not None:
        import torch

        previous = torch.get_num_threads()
        torch.set_num_threads(threads)
    try:
        _sync(name)
        start = time.perf_counter()
        run()
        _sync(name)
        seconds = time.perf_counter() - start
    finally:
        if previous is not None:
            torch.set_num_threads(previous)
    return {
        "backend": name,
        "threads": threads if name == "torch:cpu" else None,
        "n_frames": n_frames,
        "shape": tuple(shape),
        "seconds": seconds,
        "frames_per_s": n_frames / seconds,
        "mpx_per_s": n_frames * shape[0] * shape[1] / seconds / 1e6,
    }


def compare(
    n_frames: int,
    shape: tuple[int, int] = TRENCH,
    runs: list[tuple[str, int | None]] | None = None,
    repeats: int = 3,
) -> list[dict[str, Any]]:
    """:func:`measure_batch` of each ``(backend, threads)`` run, interleaved, ``repeats`` times.

    Returns one dict per run (as :func:`measure_batch`, with ``seconds``,
    ``frames_per_s`` and ``mpx_per_s`` the medians over the repeats, ``repeats`` added
    and ``vs_scipy`` the ratio of its frames/s to scipy's in the same call).
    """
    runs = available() if runs is None else runs
    results: dict[tuple, list[dict[str, Any]]] = {run: [] for run in runs}
    for _ in range(repeats):
        for backend, threads in runs:
            results[(backend, threads)].append(
                measure_batch(backend, n_frames, shape, threads=threads)
            )
    rows = []
    for measured in results.values():
        seconds = statistics.median(r["seconds"] for r in measured)
        rows.append(
            {
                **measured[0],
                "seconds": seconds,
                "frames_per_s": n_frames / seconds,
                "mpx_per_s": n_frames * shape[0] * shape[1] / seconds / 1e6,
                "repeats": repeats,
            }
        )
    scipy = next((r for r in rows if r["backend"] == "scipy"), None)
    for row in rows:
        row["vs_scipy"] = row["frames_per_s"] / scipy["frames_per_s"] if scipy else float("nan")
    return rows


NO_CUDA = "unmeasured: no CUDA GPU here"


def _cuda(n_frames: int, shape: tuple[int, int]) -> dict[str, float]:
    if ("torch:cuda", None) not in available():
        raise BenchSkipped(NO_CUDA)
    run = measure_batch("torch:cuda", n_frames, shape)
    return {
        "frame_s": run["seconds"] / n_frames,
        "frames": float(n_frames),
        "fft_s": fft_floor_s(scenes_for(shape)[0].shape),
    }


@register("gpu_trench")
def gpu_trench(config: BenchConfig) -> dict[str, float]:
    """``config.gpu_frames`` trench frames in one ``torch:cuda`` batch: ``frame_s``."""
    return _cuda(config.gpu_frames, TRENCH)


@register("gpu_field_1024")
def gpu_field_1024(config: BenchConfig) -> dict[str, float]:
    """``config.gpu_field_frames`` 1024 x 1024 fields on ``torch:cuda``: ``frame_s``."""
    return _cuda(config.gpu_field_frames, FIELD)


@register("batch_cpu_trench")
def batch_cpu_trench(config: BenchConfig) -> dict[str, float]:
    """``config.batch_frames`` trench frames on ``torch:cpu`` (one thread, as scipy's FFT)
    and on scipy, interleaved (:func:`compare`): ``frame_s`` (torch:cpu),
    ``scipy_frame_s`` and ``vs_scipy`` (torch:cpu frames/s over scipy's)."""
    runs = [("scipy", None), ("torch:cpu", 1)]
    if ("torch:cpu", 1) not in available():
        raise BenchSkipped("unmeasured: torch is not installed")
    n = config.batch_frames
    scipy, torch = compare(n, TRENCH, runs=runs, repeats=1)
    return {
        "frame_s": torch["seconds"] / n,
        "scipy_frame_s": scipy["seconds"] / n,
        "vs_scipy": torch["vs_scipy"],
        "fft_s": fft_floor_s(scenes_for(TRENCH)[0].shape),
    }
