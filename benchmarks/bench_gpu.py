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

The measuring functions live in :mod:`napari_symbac.bench.cases_gpu`, shared with
``napari-symbac bench``::

    from napari_symbac.bench.cases_gpu import compare, measure_batch
    measure_batch("torch:cpu", 64, (256, 46))   # -> dict with frames_per_s

Run: ``python benchmarks/bench_gpu.py [--quick]``
"""

from __future__ import annotations

import argparse
import os

from napari_symbac.bench.cases_gpu import FIELD, TRENCH, available, compare


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
