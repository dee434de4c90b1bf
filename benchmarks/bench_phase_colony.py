"""A phase-contrast colony frame on an agar pad: the partially coherent model against the
linear kernel, in the same run.

Simulate draws a pad in phase contrast through the partially coherent model at the
colony fit's start (`fit.colony.colony_phase_render`), a trench through the linear
kernel of eq. 7-15. This times one frame of each, rendered without noise and without
the cache (`ForwardModel.render_clean(cache=False)`, as `pipeline.iter_render` renders a
series), of the colony Simulate lays out for Omnipose's Sample000252 (564 x 564 px of
0.05734 um; `calibrate.core.rough_pad_layout`, one colony grown 58 frames; the last
frame, 181 cells, is rendered). The two renders are timed interleaved (one of each in
turn, medians of the rounds) in wall time, each render single-threaded (scipy.fft's
default). ``--against OLD_SRC`` runs the same measurement in subprocesses that
alternate between this tree's ``src`` and another checkout's (e.g. the code before a
change), so that both see the same machine load.

Needs ``../shared/data/real/omnipose/Sample000252.png`` (or ``--data``).

Run: ``python benchmarks/bench_phase_colony.py [--rounds 5] [--against OLD/src]``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
PIXEL_UM = 0.05734  # Sample000252's cells 1 um wide (docs/rendering.md)


def measure(data_dir: str, rounds: int) -> dict[str, float]:
    """Median wall seconds of one linear and one partially coherent frame."""
    import dataclasses
    import math
    import statistics
    import time

    import numpy as np

    from napari_symbac.calibrate.core import rough_pad_layout
    from napari_symbac.io import read_image
    from napari_symbac.optics import ForwardModel
    from napari_symbac.pipeline import draw_frame
    from napari_symbac.settings import Microscope, PipelineSettings, RenderSettings
    from napari_symbac.sim import Simulator

    image = np.asarray(read_image(Path(data_dir) / "omnipose" / "Sample000252.png").data)
    microscope = Microscope(pixel_size_um=PIXEL_UM, modality="phase")
    base = PipelineSettings(microscope=microscope)
    cells = base.simulation
    fields, _ = rough_pad_layout(
        image.astype(float), PIXEL_UM, cells.cell_width_um, cells.cell_max_length_um, "phase"
    )
    simulation_settings = dataclasses.replace(base.simulation, **fields)
    simulator = Simulator(simulation_settings, np.random.default_rng(simulation_settings.seed))
    for _ in simulator.iter_frames():
        pass
    simulation = simulator.result()
    # the start of the colony fit (fit.colony.colony_phase_render), written out so that
    # an older tree without it is timed on the same settings
    upsample = max(1, math.ceil(PIXEL_UM / (microscope.wavelength_um / (4 * 1.45)) - 1e-9))
    coherent = RenderSettings(
        upsample=upsample,
        psf_radius_px=max(8, round(3.0 * upsample / PIXEL_UM)),
        phase_model="partially_coherent",
        cell_intensity=99.0,
        media_intensity=99.0,
        device_intensity=99.0,
        cell_phase_rad=0.6,
        plate_transmission=0.2,
        apodisation_sigma_um=2.0,
        source_points=12,
    )
    linear = RenderSettings(cell_intensity=41.0, media_intensity=99.0, device_intensity=36.0)
    renders = {"linear_s": linear, "partially_coherent_s": coherent}
    # the last frames, one a round (a new frame each time, as a series is rendered),
    # after one before them that computes the kernels and pupils
    last = len(simulation.frames) - 1
    frames = range(last - rounds, last + 1)
    models, scenes = {}, {}
    for name, render in renders.items():
        settings = dataclasses.replace(base, simulation=simulation_settings, render=render)
        scenes[name] = [draw_frame(simulation, settings, index) for index in frames]
        models[name] = ForwardModel(microscope, render)
        models[name].render_clean(scenes[name][0], cache=False)
    times: dict[str, list[float]] = {name: [] for name in renders}
    for index in range(1, rounds + 1):
        for name in renders:
            start = time.perf_counter()
            models[name].render_clean(scenes[name][index], cache=False)
            times[name].append(time.perf_counter() - start)
    out = {name: statistics.median(values) for name, values in times.items()}
    out["cells"] = float(len(simulation.frames[last].ids))
    out["frame_px"] = float(np.prod(scenes["partially_coherent_s"][-1].cells.shape))
    return out


def _run(src: Path, data_dir: str, rounds: int) -> dict[str, float]:
    here = str(Path(__file__).parent)
    code = (
        f"import json, sys; sys.path.insert(0, {here!r}); from bench_phase_colony import "
        f"measure; print(json.dumps(measure({data_dir!r}, {rounds})))"
    )
    env = {**os.environ, "PYTHONPATH": str(src)}
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=False
    )
    if done.returncode != 0:
        raise SystemExit(f"the measurement on {src} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(DATA), help="folder of the real data")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--against", help="another checkout's src, measured alternately")
    parser.add_argument("--pairs", type=int, default=2, help="alternations with --against")
    args = parser.parse_args(argv)
    if not (Path(args.data) / "omnipose" / "Sample000252.png").is_file():
        raise SystemExit(
            f"no omnipose/Sample000252.png under {args.data}: pass --data with the folder "
            "of ../shared/data/real"
        )
    trees = {"this tree": SRC}
    if args.against:
        trees["against"] = Path(args.against)
    pairs = args.pairs if args.against else 1
    for _ in range(pairs):
        for label, src in trees.items():
            row = _run(src, args.data, args.rounds)
            ratio = row["partially_coherent_s"] / row["linear_s"]
            print(
                f"{label:10s} linear {row['linear_s']:.3f} s  partially coherent "
                f"{row['partially_coherent_s']:.3f} s  (x{ratio:.2f})  {row['cells']:.0f} cells, "
                f"{row['frame_px']:.0f} render px"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
