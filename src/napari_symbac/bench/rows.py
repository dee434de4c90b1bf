"""The rows of ``napari-symbac bench``, in the order of the table.

Importing this module registers every benchmark (the ``cases_*`` modules and the
child-process ones) and fills :data:`~napari_symbac.bench.registry.ROWS`.
"""

from __future__ import annotations

from napari_symbac.bench import (  # noqa: F401
    cases_fit,
    cases_gpu,
    cases_render,
    cases_sim,
    subprocesses,
)
from napari_symbac.bench.registry import ROWS, Row

__all__ = ["ROWS"]

_NO_FIELDS = "SyMBac has no open fields"
ROWS[:] = [
    Row("simulation, trench 15 um ({trench_frames} frames)", "sim_trench", "frame_s", "per_s",
        "frames/s", symbac_key="sim_s_per_frame"),
    *(
        Row(f"simulation, colony at {{colony_cells[{i}]}} cells, per cell-frame", "sim_colony",
            f"cell_frame_s_{i}", "ms", fft_key=None, symbac_note="SyMBac has no colony simulator")
        for i in range(3)
    ),
    Row("simulation, colony cost per cell-frame, {colony_cells[2]} / {colony_cells[0]} cells",
        "sim_colony", "ratio", "ratio", fft_key=None, symbac_note="SyMBac has no colony simulator"),
    Row("per-frame path, trench 256 x 46 (draw + cold render + masks)", "render_trench",
        "frame_s", "ms", symbac_key="render_s_per_frame"),
    Row("cached re-render (intensity change), trench", "render_trench", "cached_s", "ms",
        symbac_note="SyMBac has no cache"),
    Row("draw + masks, field 1024 x 1024 (360 cells)", "field_draw_1024", "draw_masks_s", "ms",
        symbac_note=_NO_FIELDS),
    Row("draw + masks, field 2048 x 2048 (1440 cells)", "field_draw_2048", "draw_masks_s", "ms",
        symbac_note=_NO_FIELDS),
    Row("GPU batched render per frame, trench 256 x 46 (torch:cuda, {gpu_frames} frames)",
        "gpu_trench", "frame_s", "ms"),
    Row("GPU batched render per frame, field 1024 x 1024 (torch:cuda, {gpu_field_frames} "
        "frames)", "gpu_field_1024", "frame_s", "ms"),
    Row("torch:cpu batched render per frame, 1 thread, trench ({batch_frames} frames)",
        "batch_cpu_trench", "frame_s", "ms"),
    Row("scipy render per frame, trench (same frames, interleaved)", "batch_cpu_trench",
        "scipy_frame_s", "ms"),
    Row("torch:cpu (1 thread) frames/s / scipy frames/s, trench", "batch_cpu_trench", "vs_scipy",
        "ratio", fft_key=None),
    Row("slider -> layer latency (intensity), trench", "slider", "slider_s", "ms",
        symbac_note="not measured (SyMBac's GUI is notebook widgets)"),
    Row("fit, trench 256 x 46 (fit_scene)", "fit_trench", "fit_s", "s",
        symbac_note="not measured (its optimiser takes minutes)"),
    Row("fit, field 256 x 256 fluorescence ({fit_field_cells} cells, fit_scene)", "fit_field",
        "fit_s", "s", symbac_note="SyMBac has no open-field fit"),
    Row("export, 1 worker ({export_images} images, overall)", "export_1", "image_s", "per_s",
        "images/s", symbac_key="export_overall_s_per_image"),
    Row("export, 1 worker, steady (after the first image)", "export_1", "steady_image_s",
        "per_s", "images/s", symbac_key="export_s_per_image"),
    Row("export, 2 workers ({export_images} images, overall, cluster start-up included)",
        "export_2", "image_s", "per_s", "images/s", symbac_key="export_overall_s_per_image"),
    Row("peak memory, export 1 worker (process)", "export_1", "peak_mib", "MiB", fft_key=None,
        symbac_key="peak_mib"),
    Row("peak memory, export 2 workers (largest worker process)", "export_2", "peak_worker_mib",
        "MiB", fft_key=None, symbac_note="SyMBac runs one process"),
]  # fmt: skip
