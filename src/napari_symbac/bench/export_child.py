"""One timed export in a fresh process (``python -m napari_symbac.bench.export_child``).

A fresh process per run makes its peak memory its own. Prints one JSON line: wall
seconds (simulation, cluster start-up and writing included), the steady rate after the
first finished image, peak resident memory of this process (not of dask workers), and
the FFT floor of the exported frame.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time


def run(n: int, workers: int, fmt: str) -> dict[str, float]:
    """Export ``n`` trench images (60-frame simulation, frames from 20 on) in ``fmt``."""
    from napari_symbac.bench.config import EXPORT_SIM_FRAMES
    from napari_symbac.bench.timing import fft_floor_s, peak_rss_mib
    from napari_symbac.export import ExportSettings, export_dataset
    from napari_symbac.settings import PipelineSettings, SimulationSettings

    settings = ExportSettings(
        n_items=n,
        formats=[fmt],
        seed=0,
        first_frame=20,
        pipeline=PipelineSettings(simulation=SimulationSettings(n_frames=EXPORT_SIM_FRAMES)),
    )
    out = tempfile.mkdtemp(prefix="napari-symbac-bench-")
    marks: list[tuple[float, int]] = []
    try:
        start = time.perf_counter()

        def progress(done: int, _total: int) -> None:
            marks.append((time.perf_counter(), done))

        report = export_dataset(settings, out, workers=workers, progress=progress)
        wall = time.perf_counter() - start
    finally:
        shutil.rmtree(out, ignore_errors=True)
    started = [m for m in marks if m[1] > 0]
    (t0, d0), (t1, d1) = started[0], marks[-1]
    steady = (t1 - t0) / (d1 - d0) if d1 > d0 else wall / n
    return {
        "image_s": wall / report.n_written,
        "steady_image_s": steady,
        "wall_s": wall,
        "workers": float(report.workers),
        "peak_mib": peak_rss_mib(),
        "fft_s": fft_floor_s(_frame_shape(settings), _kernel(settings)),
    }


def _frame_shape(settings) -> tuple[int, int]:
    from napari_symbac.export.dataset import _simulation
    from napari_symbac.scene import draw_scene, field_of

    pipeline = settings.pipeline
    simulation = _simulation(pipeline, settings.seed, 0)
    scene = draw_scene(
        simulation.frames[-1],
        pipeline.simulation.trench,
        pipeline.microscope,
        pipeline.render,
        field=field_of(simulation),
    )
    return scene.shape


def _kernel(settings):
    import numpy as np

    from napari_symbac.optics import ForwardModel

    p = settings.pipeline
    return np.asarray(ForwardModel(p.microscope, p.render, p.camera).kernel(), np.float32)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--n", type=int, required=True)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--format", default="omnipose")
    args = parser.parse_args()
    print(json.dumps(run(args.n, args.workers, args.format)))


if __name__ == "__main__":
    main()
