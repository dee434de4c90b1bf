"""Batched device rendering against the scipy path: frames/s for trench batches and large fields.

Times the render stage alone (scene components in, uint16 camera images out, noise
included; drawing the scenes is not timed, it is the same for both paths):

* scipy: :meth:`ForwardModel.render` (``cache=False``, the fused convolution + block
  average) frame by frame, as ``napari-symbac render --backend scipy`` does;
* torch: :class:`~napari_symbac.optics.batched.BatchedRenderer` on ``torch:cpu`` and,
  where torch sees a GPU, ``torch:cuda`` (frames batched and kept on the device).

Frames: a 256 x 46 camera-pixel trench frame (5 cells, 3x upsampling, PSF radius 50,
the project's defaults) and a square open field (``1024 x 1024`` camera pixels by
default) of cell-like blobs. Each batch cycles through a few distinct scenes (the
render cost does not depend on the content). Runs of the backends are interleaved and
repeated; the median of the repeats is reported, so ratios hold on a shared machine.

Importable (``napari-symbac bench`` uses :func:`measure_batch` and :func:`compare`)::

    from benchmarks.bench_gpu import measure_batch, compare
    measure_batch("torch:cpu", 64, (256, 46))   # -> dict with frames_per_s

Run: ``python benchmarks/bench_gpu.py [--quick]``
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from functools import lru_cache
from types import SimpleNamespace
from typing import Any

import numpy as np

from napari_symbac.optics import ForwardModel
from napari_symbac.optics.batched import BatchedRenderer, resolve_backend
from napari_symbac.scene import Scene, draw_scene
from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry

__all__ = ["available", "compare", "measure_batch", "scenes_for"]

TRENCH = (256, 46)
FIELD = (1024, 1024)
MICROSCOPE = Microscope()
RENDER = RenderSettings()  # psf radius 50, upsample 3, camera noise
CAMERA = Camera()


def _trench_cells(shift_um: float) -> SimpleNamespace:
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
            draw_scene(_trench_cells(0.3 * k), geometry, MICROSCOPE, RENDER)
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


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer frames and repeats")
    args = parser.parse_args(argv)
    trench_frames, field_frames, repeats = (100, 2, 1) if args.quick else (1000, 6, 3)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"load average at start: {load:.2f}; cores: {os.cpu_count()}")
    cases = [("trench 256 x 46", TRENCH, trench_frames), ("field 1024 x 1024", FIELD, field_frames)]
    print(f"{'frames':<20}{'n':>6}  {'backend':<24}{'frames/s':>10}{'Mpx/s':>9}{'vs scipy':>10}")
    for label, shape, n in cases:
        for row in compare(n, shape, repeats=repeats):
            name = row["backend"]
            if name == "torch:cpu":
                name += f" ({row['threads'] or 'default'} thr)"
            print(
                f"{label:<20}{n:>6}  {name:<24}{row['frames_per_s']:>10.1f}"
                f"{row['mpx_per_s']:>9.2f}{row['vs_scipy']:>9.2f}x"
            )
        if ("torch:cuda", None) not in available():
            print(f"{label:<20}{n:>6}  {'torch:cuda':<24}{'unmeasured (no GPU here)':>29}")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"load average at end: {load:.2f}")


if __name__ == "__main__":
    main()
