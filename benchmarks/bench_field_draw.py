"""Field drawing (scene + masks) of this tree against another, and where its time goes.

``measure_field_draw`` (napari_symbac.bench.cases_render) of the 1024 x 1024 field of
360 cells and the 2048 x 2048 field of 1440 cells, run in subprocesses that alternate
between this source tree and ``--against`` (another checkout's ``src``, e.g. the
code before a change), so that both see the same machine load; each run prints its
ratio to the FFT floor measured in the same run. ``--breakdown`` then times the
parts of this tree's drawing in one process, interleaved with the floor: the whole
``draw_scene``, the same cells all straight (the difference is the bent cells' eq. 1,
a libm sine a pixel), the masks, a draw of the same number of tiny cells (the
per-cell and per-frame fixed cost), the first touch of a new frame-sized float32
image, and the media image's first read. CPU time of the measuring thread, medians.
``--first-call`` times, in fresh processes, what the compiled drawing (numba) costs
once per process: importing ``napari_symbac.scene`` (numba with it) and the first
``draw_scene`` + masks + ``chord`` of a small scene, with an empty kernel cache (they
compile) and then twice with the cache the first run wrote (they load), in wall time.

Run: ``python benchmarks/bench_field_draw.py --against /path/to/old/src [--pairs 3]
[--breakdown] [--quick] [--first-call]``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SRC = Path(__file__).resolve().parents[1] / "src"
MEASURE = (
    "import json; from napari_symbac.bench.cases_render import measure_field_draw; "
    "print(json.dumps(measure_field_draw({size}, {cells}, rounds={rounds})))"
)


def _run(src: Path, size: int, cells: int, rounds: int) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src)}
    code = MEASURE.format(size=size, cells=cells, rounds=rounds)
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def compare(against: Path, cases: list[tuple[int, int]], pairs: int, rounds: int) -> None:
    print(f"{'tree':<8}{'field':>7}{'draw ms':>9}{'masks ms':>10}{'floor ms':>10}"
          f"{'/ floor':>9}{'load':>6}")
    for _ in range(pairs):
        for tag, src in (("before", against), ("after", SRC)):
            for size, cells in cases:
                r = _run(src, size, cells, rounds)
                print(
                    f"{tag:<8}{size:>7}{r['draw_s'] * 1e3:>9.1f}{r['masks_s'] * 1e3:>10.1f}"
                    f"{r['fft_floor_s'] * 1e3:>10.1f}{r['draw_masks_over_floor']:>9.3f}"
                    f"{os.getloadavg()[0]:>6.1f}",
                    flush=True,
                )


FIRST_CALL = """
import json, time
t0 = time.perf_counter()
import numpy as np
from types import SimpleNamespace
from napari_symbac.scene import Field, draw_scene
from napari_symbac.scene._raster import chord
from napari_symbac.settings import Microscope, RenderSettings, TrenchGeometry
t1 = time.perf_counter()
cells = SimpleNamespace(ids=np.arange(1, 4), x_um=np.array([2.0, 4.0, 6.0]),
    y_um=np.full(3, 3.0), angle_rad=np.array([0.0, 0.5, 1.0]), length_um=np.full(3, 3.0),
    width_um=np.full(3, 1.0))
args = (cells, TrenchGeometry(), Microscope(), RenderSettings(upsample=3, psf_radius_px=10),
        {2: (0.1, 1.0, 0.0)})
def once():
    scene = draw_scene(*args, field=Field(8.0, 6.0))
    scene.camera_labels(), scene.semantic_mask()
    chord(np.arange(5.0), np.arange(4.0), (1.0, 1.0), 0.3, 2.0, 1.0, None)
t2 = time.perf_counter(); once(); t3 = time.perf_counter(); once(); t4 = time.perf_counter()
print(json.dumps({"import_s": t1 - t0, "first_s": t3 - t2, "second_s": t4 - t3}))
"""


def first_call() -> None:
    print(f"{'kernel cache':<14}{'import s':>10}{'first call s':>14}{'then ms':>9}{'load':>6}")
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "PYTHONPATH": str(SRC), "NUMBA_CACHE_DIR": cache}
        for tag in ("empty", "written", "written"):
            out = subprocess.run([sys.executable, "-c", FIRST_CALL], env=env,
                                 capture_output=True, text=True, check=True)
            r = json.loads(out.stdout.strip().splitlines()[-1])
            print(f"{tag:<14}{r['import_s']:>10.2f}{r['first_s']:>14.2f}"
                  f"{r['second_s'] * 1e3:>9.2f}{os.getloadavg()[0]:>6.1f}", flush=True)


def breakdown(size: int, n_cells: int, rounds: int) -> None:
    from napari_symbac.bench.cases_render import colony_cells
    from napari_symbac.bench.timing import fft_floor
    from napari_symbac.optics import ForwardModel
    from napari_symbac.scene import Field, draw_scene
    from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry

    microscope = Microscope()
    render = RenderSettings(upsample=3, psf_radius_px=50)
    cells, curvature, side = colony_cells(size, n_cells, pixel_um=microscope.pixel_size_um)
    field, trench = Field(side, side), TrenchGeometry()
    scene = draw_scene(cells, trench, microscope, render, curvature, field=field)
    shape = scene.shape
    floor = fft_floor(scene.cells, ForwardModel(microscope, render, Camera()).kernel())
    del scene

    tiny = type(cells)(**vars(cells))
    tiny.length_um, tiny.width_um = cells.length_um * 0.02, cells.width_um * 0.02
    tiny_bend = dict.fromkeys(curvature, (0.001, 1.0, 0.0))

    def fresh_frame() -> None:
        np.zeros(shape, np.float32).ravel()[::1024] = 1  # one write per 4 kB page

    names = ("draw_scene", "all straight", "masks", "media, first read",
             "tiny-cell draw_scene", "new float32 frame", "FFT floor")
    times: dict[str, list[float]] = {name: [] for name in names}

    def timed(name: str, fn, *args, **kwargs):
        start = time.thread_time()
        result = fn(*args, **kwargs)
        times[name].append(time.thread_time() - start)
        return result

    for _ in range(rounds):
        new = timed("draw_scene", draw_scene, cells, trench, microscope, render, curvature,
                    field=field)
        timed("masks", lambda s: (s.camera_labels(), s.semantic_mask()), new)
        timed("media, first read", getattr, new, "media")
        del new
        timed("all straight", draw_scene, cells, trench, microscope, render, None, field=field)
        timed("tiny-cell draw_scene", draw_scene, tiny, trench, microscope, render, tiny_bend,
              field=field)
        timed("new float32 frame", fresh_frame)
        timed("FFT floor", floor)
    med = {name: float(np.median(v)) for name, v in times.items()}
    print(f"\n{size} x {size} px, {n_cells} cells, render {shape[0]} x {shape[1]}, "
          f"{rounds} rounds, load {os.getloadavg()[0]:.1f}")
    for name in names:
        print(f"  {name:<24}{med[name] * 1e3:>9.1f} ms{med[name] / med['FFT floor']:>8.3f} x floor")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--against", type=Path, help="another tree's src to compare with")
    parser.add_argument("--pairs", type=int, default=3, help="before/after pairs")
    parser.add_argument("--breakdown", action="store_true", help="time this tree's parts")
    parser.add_argument("--quick", action="store_true", help="the 1024 field only")
    parser.add_argument("--first-call", action="store_true",
                        help="the compiled kernels' cost once per process")
    args = parser.parse_args(argv)
    cases = [(1024, 360)] if args.quick else [(1024, 360), (2048, 1440)]
    if args.against is not None:
        if not (args.against / "napari_symbac").is_dir():
            parser.error(f"--against {args.against}: no napari_symbac package there (give a src)")
        compare(args.against, cases, args.pairs, rounds=5)
    if args.breakdown:
        for size, n_cells in cases:
            breakdown(size, n_cells, rounds=5)
    if args.first_call:
        first_call()
    if args.against is None and not args.breakdown and not args.first_call:
        parser.error("give --against SRC, --breakdown and/or --first-call")


if __name__ == "__main__":
    main()
