"""The rows of ``napari-symbac bench``, in the order of the table.

Importing this module registers every benchmark (the ``cases_*`` modules and the
child-process ones) and fills :data:`~napari_symbac.bench.registry.ROWS`.
"""

from __future__ import annotations

from napari_symbac.bench import cases_fit, cases_render, cases_sim, subprocesses  # noqa: F401
from napari_symbac.bench.registry import ROWS, Row

__all__ = ["ROWS"]

_NO_FIELDS = "no open fields"
ROWS[:] = [
    Row("simulation, trench 15 um ({trench_frames} frames)", "sim_trench", "frame_s", "per_s",
        "frames/s", symbac_key="sim_s_per_frame"),
    *(
        Row(f"simulation, colony at {{colony_cells[{i}]}} cells", "sim_colony", f"frame_s_{i}",
            "per_s", "frames/s", fft_key=f"fft_s_{i}", symbac_note="no colony simulator")
        for i in range(3)
    ),
    Row("cold render per frame, trench 256 x 46 (draw + render + masks)", "render_trench",
        "frame_s", "ms", symbac_key="render_s_per_frame"),
    Row("cold render per frame, field 512 x 512 ({field_cells[0]} cells)", "render_field_512",
        "frame_s", "ms", symbac_note=_NO_FIELDS),
    Row("cold render per frame, field 1024 x 1024 ({field_cells[1]} cells)",
        "render_field_1024", "frame_s", "ms", symbac_note=_NO_FIELDS),
    Row("GPU cold render per frame, trench 256 x 46", "gpu_trench", "frame_s", "ms",
        symbac_note="-"),
    Row("GPU cold render per frame, field 1024 x 1024 ({field_cells[1]} cells)",
        "gpu_field_1024", "frame_s", "ms", symbac_note="-"),
    Row("cached re-render (intensity change), trench", "render_trench", "cached_s", "ms",
        symbac_note="no cache"),
    Row("slider -> layer latency (intensity), trench", "slider", "slider_s", "ms",
        symbac_note="no GUI", needs="gui"),
    Row("fit, trench 256 x 46 (fit_scene)", "fit_trench", "fit_s", "s",
        symbac_note="not run (its optimiser takes minutes)"),
    Row("fit, field 256 x 256 fluorescence (fit_scene)", "fit_field", "fit_s", "s",
        symbac_note="no open-field fit"),
    Row("export, 1 worker ({export_images} images, overall)", "export_1", "image_s", "per_s",
        "images/s", symbac_key="export_overall_s_per_image"),
    Row("export, 1 worker, steady (after the first image)", "export_1", "steady_image_s",
        "per_s", "images/s", symbac_key="export_s_per_image"),
    Row("export, 2 workers ({export_images} images, overall)", "export_2", "image_s", "per_s",
        "images/s", symbac_key="export_overall_s_per_image"),
    Row("peak memory, export 1 worker (process)", "export_1", "peak_mib", "MiB", fft_key=None,
        symbac_key="peak_mib"),
]  # fmt: skip
