"""The batched device path for every modality and the depth stage, against the scipy path.

Trench frames drawn from a real simulation (40 frames, seed 1; its last 20 scenes cycled
to ``--frames`` frames, camera noise included) are rendered by the scipy path frame by
frame (``ForwardModel.render(cache=False)``) and by one
:meth:`~napari_symbac.optics.batched.BatchedRenderer.render` call on torch's device
(``torch:cuda`` where torch sees a GPU, else ``torch:cpu``), interleaved and repeated; the
medians are reported, with the largest difference of the noise-free batch from
``ForwardModel.render_clean`` over the range of the 20 scenes. Cases: phase contrast,
bright field, fluorescence, and fluorescence through the depth stage (eq. 16, 5 slabs,
a volume stain on the static path and an envelope stain composed).

Run: ``python benchmarks/bench_gpu_modalities.py [--frames N] [--repeats R]``
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import time

import numpy as np

from napari_symbac.optics import ForwardModel
from napari_symbac.optics.batched import BatchedRenderer, resolve_backend
from napari_symbac.pipeline import iter_scenes
from napari_symbac.settings import (
    Microscope,
    PipelineSettings,
    RenderSettings,
    SimulationSettings,
)
from napari_symbac.sim import simulate

FLUORESCENCE = {"cell_intensity": 2000.0, "media_intensity": 150.0, "device_intensity": 100.0}
DEPTH = {**FLUORESCENCE, "depth_layers": 5, "focus_offset_um": 0.2}
CASES = {
    "phase": (Microscope(), RenderSettings()),
    "brightfield": (Microscope(modality="brightfield"), RenderSettings()),
    "fluorescence": (Microscope(modality="fluorescence"), RenderSettings(**FLUORESCENCE)),
    "depth, volume stain": (Microscope(modality="fluorescence"), RenderSettings(**DEPTH)),
    "depth, envelope stain": (
        Microscope(modality="fluorescence"),
        RenderSettings(**DEPTH, envelope_stain_fraction=0.6),
    ),
}


def _sync(device: str) -> None:
    if device == "cuda":
        import torch

        torch.cuda.synchronize()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1000, help="frames per batch")
    parser.add_argument("--repeats", type=int, default=3, help="interleaved repeats")
    args = parser.parse_args(argv)
    device = resolve_backend("torch").partition(":")[2]
    print(f"torch:{device}; load average {os.getloadavg()[0]:.2f}; cores {os.cpu_count()}")
    sim_settings = SimulationSettings(n_frames=40, seed=1)
    simulation = simulate(sim_settings)
    print(f"{'trench frames':<24}{'n':>6}{'scipy f/s':>11}{'torch f/s':>11}{'ratio':>8}"
          f"{'noise-free max diff / range':>30}")  # fmt: skip
    for name, (microscope, render) in CASES.items():
        pipeline = PipelineSettings(simulation=sim_settings, render=render, microscope=microscope)
        pool = list(iter_scenes(simulation, pipeline))[-20:]
        scenes = [pool[i % len(pool)] for i in range(args.frames)]
        model = ForwardModel(microscope, render, pipeline.camera)
        renderer = BatchedRenderer(model, device)
        rng = np.random.default_rng(0)
        model.render(scenes[0], rng, cache=False)  # warm-up: kernels, spectra, device
        renderer.render(scenes[:2], rng)
        seconds: dict[str, list[float]] = {"scipy": [], "torch": []}
        for _ in range(args.repeats):
            start = time.perf_counter()
            for scene in scenes:
                model.render(scene, rng, cache=False)
            seconds["scipy"].append(time.perf_counter() - start)
            _sync(device)
            start = time.perf_counter()
            renderer.render(scenes, rng)
            _sync(device)
            seconds["torch"].append(time.perf_counter() - start)
        scipy_fps, torch_fps = (args.frames / statistics.median(seconds[k]) for k in seconds)
        clean = ForwardModel(
            microscope, dataclasses.replace(render, noise_model="none"), pipeline.camera
        )
        expected = np.stack([clean.render_clean(scene, cache=False) for scene in pool])
        got = BatchedRenderer(clean, device).render_clean(pool)
        difference = float(np.abs(got - expected).max() / np.ptp(expected))
        print(f"{name:<24}{args.frames:>6}{scipy_fps:>11.1f}{torch_fps:>11.1f}"
              f"{torch_fps / scipy_fps:>7.1f}x{difference:>30.2e}")  # fmt: skip
    print(f"load average at end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
