"""The shared render path (pipeline.py): scenes drawn by threads ahead of the renderer."""

from __future__ import annotations

import threading

import numpy as np

from napari_symbac import pipeline
from napari_symbac.pipeline import iter_render
from napari_symbac.settings import AgarPadGeometry, PipelineSettings, SimulationSettings
from napari_symbac.sim import simulate


def _drawing_threads() -> set[threading.Thread]:
    return {t for t in threading.enumerate() if t.name.startswith("napari-symbac-draw")}


def test_threaded_drawing_renders_the_same_bits(monkeypatch):
    trench = PipelineSettings(simulation=SimulationSettings(n_frames=12, seed=4))
    pad = PipelineSettings(
        simulation=SimulationSettings(
            geometry="agar_pad", n_frames=10, agar_pad=AgarPadGeometry(12.0, 10.0), seed=2
        )
    )
    before = _drawing_threads()  # a render of an earlier test not yet collected
    for settings in (trench, pad):
        simulation = simulate(settings.simulation)
        monkeypatch.setattr(pipeline, "DRAW_THREADS", 1)
        one = list(iter_render(simulation, settings))
        monkeypatch.setattr(pipeline, "DRAW_THREADS", 4)
        four = list(iter_render(simulation, settings))
        assert len(one) == len(four) == len(simulation.frames)
        for frame_one, frame_four in zip(one, four):
            for a, b in zip(frame_one, frame_four):  # image, labels, semantic
                np.testing.assert_array_equal(a, b)
        assert _drawing_threads() <= before


def test_a_render_stopped_early_leaves_no_drawing_thread(monkeypatch):
    settings = PipelineSettings(simulation=SimulationSettings(n_frames=30, seed=1))
    simulation = simulate(settings.simulation)
    monkeypatch.setattr(pipeline, "DRAW_THREADS", 3)
    before = _drawing_threads()
    frames = iter_render(simulation, settings)
    image, labels, _ = next(frames)
    assert image.dtype == np.uint16
    assert labels.max() > 0
    assert _drawing_threads() - before  # drawing ahead, on its own threads
    frames.close()
    assert _drawing_threads() <= before
