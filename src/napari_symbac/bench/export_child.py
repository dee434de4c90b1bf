"""One timed export in a fresh process (``python -m napari_symbac.bench.export_child``).

A fresh process per run makes its peak memory its own. Prints one JSON line: wall
seconds (simulation, cluster start-up and writing included), the steady rate after the
first finished image, the workers that wrote, peak resident memory of this process and,
when the export ran on a local dask cluster, of its largest worker process
(``peak_worker_mib``), and the FFT floor of the exported frame.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import shutil
import tempfile
import time
from collections.abc import Iterator
from typing import Any


def run(n: int, workers: int, fmt: str) -> dict[str, float]:
    """Export ``n`` trench images (60-frame simulation, frames from 20 on) in ``fmt``.

    Returns
    -------
    dict
        ``image_s`` (wall seconds per image), ``steady_image_s``, ``wall_s``,
        ``workers``, ``peak_mib`` (this process), ``fft_s`` and, only when a local
        cluster was started, ``peak_worker_mib``: the largest peak resident memory of
        its worker processes, read on each worker just before the cluster closes.
    """
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
    worker_peaks_mib: list[float] = []
    try:
        start = time.perf_counter()

        def progress(done: int, _total: int) -> None:
            marks.append((time.perf_counter(), done))

        with _recording_worker_peaks(worker_peaks_mib):
            report = export_dataset(settings, out, workers=workers, progress=progress)
        wall = time.perf_counter() - start
    finally:
        shutil.rmtree(out, ignore_errors=True)
    started = [m for m in marks if m[1] > 0]
    (t0, d0), (t1, d1) = started[0], marks[-1]
    steady = (t1 - t0) / (d1 - d0) if d1 > d0 else wall / n
    result = {
        "image_s": wall / report.n_written,
        "steady_image_s": steady,
        "wall_s": wall,
        "workers": float(report.workers),
        "peak_mib": peak_rss_mib(),
        "fft_s": fft_floor_s(_frame_shape(settings), _kernel(settings)),
    }
    if worker_peaks_mib:
        result["peak_worker_mib"] = max(worker_peaks_mib)
    return result


@contextlib.contextmanager
def _recording_worker_peaks(peaks_mib: list[float]) -> Iterator[None]:
    """Append each dask worker's peak resident memory (MiB) to ``peaks_mib``.

    The export starts and closes its local cluster itself: its call that closes the
    client (``runner.close_quietly``) is wrapped, for this run only, so that each worker
    reports :func:`~napari_symbac.bench.timing.peak_rss_mib` (its own ``VmHWM``) first.
    Nothing is appended when the export ran in this process.
    """
    from napari_symbac.bench.timing import peak_rss_mib
    from napari_symbac.export import runner

    close = runner.close_quietly

    def close_after_reading(client: Any | None, cluster: Any | None) -> None:
        if client is not None:
            with contextlib.suppress(Exception):
                peaks_mib.extend(client.run(peak_rss_mib).values())
        close(client, cluster)

    runner.close_quietly = close_after_reading
    try:
        yield
    finally:
        runner.close_quietly = close


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
