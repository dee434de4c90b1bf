"""Render rows: a trench frame, open fields of 512 and 1024 camera px, cached re-render.

Each frame is the full per-frame path of an export or a preview: draw the scene, render
it cold (``cache=False``: compose, convolve once, camera noise) and make its instance and
semantic masks. Stand-ins until the render helper's ``measure_*`` functions are
registered under the same names (``render_trench``, ``render_field``) with these keys.
"""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np

from napari_symbac.bench.config import BenchConfig
from napari_symbac.bench.registry import register
from napari_symbac.bench.timing import fft_floor_s, median_s

__all__ = [
    "TRENCH_256",
    "cuda_backend",
    "field_cells",
    "gpu_field_1024",
    "gpu_trench",
    "render_field_512",
    "render_field_1024",
    "render_trench",
    "trench_cells",
    "trench_frame",
]

#: The 256 x 46 camera-px trench of docs/benchmarks.md.
TRENCH_256 = {"length_um": 15.84, "width_um": 1.4, "margin_um": 0.8}


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


def field_cells(side_px: int, count: int, pixel_size_um: float, rng: np.random.Generator):
    """``count`` cells on a jittered grid of a ``side_px`` square field (no overlaps)."""
    per_row = int(np.ceil(np.sqrt(count)))
    pitch = side_px * pixel_size_um / per_row
    ix, iy = np.meshgrid(np.arange(per_row), np.arange(per_row))
    jitter = 0.1 * pitch
    x = ((ix.ravel() + 0.5) * pitch)[:count] + rng.uniform(-jitter, jitter, count)
    y = ((iy.ravel() + 0.5) * pitch)[:count] + rng.uniform(-jitter, jitter, count)
    return SimpleNamespace(
        ids=np.arange(1, count + 1),
        x_um=x,
        y_um=y,
        angle_rad=rng.uniform(-np.pi, np.pi, count),
        length_um=np.minimum(rng.uniform(2.0, 3.5, count), 0.7 * pitch),
        width_um=np.full(count, min(1.0, 0.3 * pitch)),
    )


def _frame_path(model, draw, frames: int, rng: np.random.Generator) -> dict[str, float]:
    """Median seconds of draw + cold render + masks over ``frames`` new scenes."""
    scenes = iter([draw(k) for k in range(frames + 1)])
    first = next(scenes)
    model.render(first, rng, cache=False)  # kernel and its spectrum
    keys = iter(range(frames + 1, 2 * frames + 2))

    def full() -> None:
        scene = draw(next(keys))
        model.render(scene, rng, cache=False)
        scene.camera_labels()
        scene.semantic_mask()

    timings = {
        "frame_s": median_s(full, frames),
        "draw_s": median_s(lambda: draw(0), frames),
        "render_s": median_s(lambda: model.render(next(scenes), rng, cache=False), frames),
    }
    fresh = iter([draw(k) for k in range(frames)])

    def masks() -> None:
        scene = next(fresh)
        scene.camera_labels()
        scene.semantic_mask()

    timings["masks_s"] = median_s(masks, frames)
    return timings


def trench_frame(
    config: BenchConfig, psf_radius_px: int = 50, backend: str = "scipy"
) -> dict[str, float]:
    """The 256 x 46 trench (5 cells, upsample 3) at PSF radius ``psf_radius_px``.

    ``frame_s`` (draw + cold render + masks), its parts, ``cached_s`` (re-render after
    an intensity change: no convolution), ``fft_s``, and the frame's shapes (for
    SyMBac's canvas).
    """
    from napari_symbac.optics import ForwardModel
    from napari_symbac.scene import draw_scene
    from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry

    microscope, camera = Microscope(), Camera()
    render = RenderSettings(upsample=3, psf_radius_px=psf_radius_px)
    trench = TrenchGeometry(**TRENCH_256)
    rng = np.random.default_rng(0)
    model = ForwardModel(microscope, render, camera, backend=backend)

    def draw(k: int):
        return draw_scene(trench_cells(0.004 * k), trench, microscope, render)

    result = _frame_path(model, draw, config.render_frames, rng)
    scene = draw(0)
    model.render(scene, rng)
    changed = iter(
        [dataclasses.replace(render, cell_intensity=1000.0 + k) for k in range(100)]
    )
    repeats = max(5, config.render_frames)
    result["cached_s"] = median_s(
        lambda: model.with_render(next(changed)).render(scene, rng), repeats
    )
    result["fft_s"] = fft_floor_s(scene.shape, np.asarray(model.kernel(), np.float32))
    result["render_rows"], result["render_cols"] = map(float, scene.shape)
    result["camera_rows"], result["camera_cols"] = map(float, scene.camera_shape)
    return result


@register("render_trench")
def render_trench(config: BenchConfig) -> dict[str, float]:
    """The 256 x 46 trench at PSF radius 50 (see :func:`trench_frame`)."""
    return trench_frame(config)


def _field(side_px: int, count: int, frames: int, backend: str = "scipy") -> dict[str, float]:
    from napari_symbac.optics import ForwardModel
    from napari_symbac.scene import Field, draw_scene
    from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry

    microscope, camera = Microscope(), Camera()
    render = RenderSettings(upsample=3, psf_radius_px=50)
    px = microscope.pixel_size_um
    field = Field(side_px * px, side_px * px)
    model = ForwardModel(microscope, render, camera, backend=backend)
    rng = np.random.default_rng(0)

    def draw(k: int):
        cells = field_cells(side_px, count, px, np.random.default_rng(k))
        return draw_scene(cells, TrenchGeometry(), microscope, render, field=field)

    result = _frame_path(model, draw, frames, rng)
    result["fft_s"] = fft_floor_s(draw(0).shape, np.asarray(model.kernel(), np.float32), 3)
    result["cells"] = float(count)
    return result


@register("render_field_512")
def render_field_512(config: BenchConfig) -> dict[str, float]:
    """A 512 x 512 camera-px open field of ``config.field_cells[0]`` cells (phase)."""
    return _field(512, config.field_cells[0], max(2, config.render_frames // 4))


@register("render_field_1024")
def render_field_1024(config: BenchConfig) -> dict[str, float]:
    """A 1024 x 1024 camera-px open field of ``config.field_cells[1]`` cells (phase)."""
    return _field(1024, config.field_cells[1], max(2, config.render_frames // 4))


def cuda_backend() -> str:
    """``"torch:cuda"`` or ``"cupy"`` where a CUDA device answers, else :class:`BenchSkipped`."""
    import importlib.util

    from napari_symbac.bench.subprocesses import BenchSkipped

    if importlib.util.find_spec("torch") is not None:
        import torch

        if torch.cuda.is_available():
            return "torch:cuda"
    if importlib.util.find_spec("cupy") is not None:
        import cupy

        try:
            if cupy.cuda.runtime.getDeviceCount() > 0:
                return "cupy"
        except cupy.cuda.runtime.CUDARuntimeError:
            pass
    raise BenchSkipped("unmeasured: no CUDA GPU here")


@register("gpu_trench")
def gpu_trench(config: BenchConfig) -> dict[str, float]:
    """The trench frame of :func:`render_trench` on the GPU backend (same keys).

    A stand-in over today's backend: the GPU helper's batched measurement (1000 frames
    kept on the device) registers under this name at merge.
    """
    return trench_frame(config, backend=cuda_backend())


@register("gpu_field_1024")
def gpu_field_1024(config: BenchConfig) -> dict[str, float]:
    """The 1024 x 1024 field of :func:`render_field_1024` on the GPU backend."""
    return _field(1024, config.field_cells[1], max(2, config.render_frames // 4), cuda_backend())
