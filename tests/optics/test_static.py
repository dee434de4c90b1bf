"""Static layers of bulk rendering: open and device convolved once, cells circularly."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from napari_symbac.bench.cases_render import trench_cells, trench_settings
from napari_symbac.optics import ForwardModel
from napari_symbac.optics.backends import ScipyBackend, resample_fft_shape
from napari_symbac.optics.static import axis_window, static_layers
from napari_symbac.pipeline import apply_cell_brightness
from napari_symbac.scene import Field, add_media_texture, draw_scene
from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry

MIC = Microscope()
RS = RenderSettings(psf_radius_px=30, noise_model="none")
TRENCH = TrenchGeometry(length_um=6.0, width_um=1.4, margin_um=0.8)


def _composed(model: ForwardModel, scene) -> np.ndarray:
    """The render of the composed image (eq. 3 first, one convolution): a copy of the
    scene without its static layers."""
    copy = scene.replace_media(scene.media)
    assert static_layers(copy) is None
    return model.render_clean(copy, cache=False)


def _fast(model: ForwardModel, scene) -> np.ndarray:
    """``render_clean(cache=False)`` on the static path: the model's first frame of a
    geometry is composed (unless its static layers are cached), the second static."""
    first = model.render_clean(scene, cache=False)
    second = model.render_clean(scene, cache=False)
    assert model._static_plan(scene) is not None
    _close(second, first)
    return second


def _close(a: np.ndarray, b: np.ndarray) -> None:
    assert a.dtype == b.dtype == np.float32
    assert a.shape == b.shape
    assert np.abs(a - b).max() <= 2e-6 * np.ptp(b) + 1e-3


@pytest.mark.parametrize("factor", [1, 2, 3])
def test_circular_window_equals_the_linear_convolution(factor):
    """Random supports (inside, at the edges, partly and wholly outside the view):
    the windowed circular transform gives the full frame's camera pixels."""
    rng = np.random.default_rng(factor)
    backend = ScipyBackend()
    narrowed = 0
    for _ in range(40):
        ky, kx = (int(v) * 2 + 1 for v in rng.integers(2, 12, 2))
        rows, cols = (factor * int(v) for v in rng.integers(3, 30, 2))
        height, width = rows + ky - 1, cols + kx - 1
        kernel = rng.random((ky, kx)).astype(np.float32)
        r0, c0 = (int(v) for v in rng.integers(0, (height, width)))
        r1 = int(rng.integers(r0 + 1, height + 1))
        c1 = int(rng.integers(c0 + 1, width + 1))
        image = np.zeros((height, width), np.float32)
        image[r0:r1, c0:c1] = rng.random((r1 - r0, c1 - c0))
        expected = backend.convolve_resample(image[None], kernel, factor)[0]
        full = resample_fft_shape(height, width, factor)
        wr = axis_window((r0, r1), height, ky, factor, full[0])
        wc = axis_window((c0, c1), width, kx, factor, full[1], real=True)
        got = np.zeros_like(expected)
        if wr is not None and wc is not None:
            assert wr.length <= full[0]
            assert wc.length <= full[1]
            narrowed += wr.length < full[0] or wc.length < full[1]
            got[wr.out_start : wr.out_stop, wc.out_start : wc.out_stop] = (
                backend.convolve_resample_circular(
                    image[wr.start : wr.stop, wc.start : wc.stop],
                    kernel,
                    factor,
                    (wr.length, wc.length),
                    (wr.out_stop - wr.out_start, wc.out_stop - wc.out_start),
                )
            )
        np.testing.assert_allclose(got, expected, atol=2e-5 * max(1.0, expected.max()))
    assert narrowed >= 10  # the shorter, circular transforms were exercised


def test_trench_cells_take_a_narrower_transform():
    """The benchmark trench: its cells need 162 transform columns, not the frame's 240."""
    microscope, render, trench, _ = trench_settings()
    scene = draw_scene(trench_cells(0.0), trench, microscope, render)
    layers = static_layers(scene)
    assert layers is not None
    assert np.array_equal(scene.media, layers.open - scene.cells)
    height, width = scene.shape
    full = resample_fft_shape(height, width, 3)
    assert full == (882, 240)
    kernel = render.psf_radius_px * 2 + 1
    cols = axis_window(layers.extent[2:], width, kernel, 3, full[1], real=True)
    assert cols is not None
    assert (cols.length, cols.out_start, cols.out_stop) == (162, 0, 46)
    assert axis_window(layers.extent[:2], height, kernel, 3, full[0]).length == 882


@pytest.mark.parametrize(
    "case",
    ["phase", "separate", "fluorescence", "round", "crop", "walls", "pad", "trim", "empty"],
)
def test_static_render_equals_the_composed_render(cells_factory, case):
    microscope, render, trench = MIC, RS, TRENCH
    cells = cells_factory([1.6, 4.4], x_um=0.7, width_um=1.0)
    kwargs: dict = {}
    if case == "separate":
        render = dataclasses.replace(RS, cell_phase_adu=300.0, device_phase_adu=120.0)
    elif case == "fluorescence":
        microscope = dataclasses.replace(MIC, modality="fluorescence")
        render = dataclasses.replace(RS, cell_intensity=900.0, media_intensity=40.0)
    elif case == "round":
        trench = dataclasses.replace(TRENCH, closed_end="round")
    elif case == "crop":
        kwargs = {"trench_origin_um": (1.5, 0.3), "camera_shape": (70, 60)}
    elif case in ("walls", "pad"):
        walls = (((1.0, 0.0), (1.0, 7.0)),) if case == "walls" else ()
        kwargs = {"field": Field(5.0, 7.0, origin_um=(-1.0, 0.0), walls_um=walls)}
        cells = cells_factory([1.6, 4.4], x_um=2.5, angle_rad=0.4, width_um=1.0)
    elif case == "empty":
        cells = cells_factory([])
    scene = draw_scene(cells, trench, microscope, render, **kwargs)
    if case == "trim":  # drawn with a wider border than the model's PSF radius
        scene = draw_scene(cells, trench, microscope, dataclasses.replace(RS, psf_radius_px=40))
    assert static_layers(scene) is not None
    model = ForwardModel(microscope, render, Camera())
    fast = _fast(model, scene)
    _close(fast, _composed(model, scene))
    _close(fast, model.render_clean(scene))  # the cached path: each component alone


def test_the_static_cache_is_never_stale(cells_factory):
    """One model (and its ``with_render`` copies, which share the cache) across
    geometries, intensities and kernels: every render equals the composed one."""
    model = ForwardModel(MIC, RS, Camera())
    narrow = draw_scene(cells_factory([2.0]), TRENCH, MIC, RS)
    wide = draw_scene(
        cells_factory([2.0], x_um=1.2), dataclasses.replace(TRENCH, width_um=2.4), MIC, RS
    )
    shifted = draw_scene(cells_factory([2.0]), TRENCH, MIC, RS, trench_origin_um=(0.6, 0.8))
    variants = [
        model,
        model.with_render(dataclasses.replace(RS, media_intensity=3000.0, device_intensity=200.0)),
        model.with_render(dataclasses.replace(RS, apodisation_sigma_um=0.5)),
        model.with_render(dataclasses.replace(RS, defocus_sigma_um=0.1)),
        model.with_render(dataclasses.replace(RS, cell_phase_adu=250.0, device_phase_adu=90.0)),
        model.with_microscope(dataclasses.replace(MIC, wavelength_um=0.55)),
    ]
    for variant in variants + variants[::-1]:
        for scene in (narrow, wide, shifted, narrow):
            _close(_fast(variant, scene), _composed(variant, scene))


def test_modified_scenes_take_the_composed_path(cells_factory):
    """Texture (media) and per-cell brightness (cells) break ``media = open - cells``."""
    scene = draw_scene(cells_factory([1.6, 4.4]), TRENCH, MIC, RS)
    model = ForwardModel(MIC, RS, Camera())
    for modified in (add_media_texture(scene, 0.2, 3), apply_cell_brightness(scene, 0.3, 3)):
        assert static_layers(modified) is None
        fast = model.render_clean(modified, cache=False)
        _close(fast, model.render_clean(modified))
        assert np.abs(fast - model.render_clean(scene, cache=False)).max() > 1.0


def test_partially_coherent_render_is_untouched(cells_factory):
    render = dataclasses.replace(RS, phase_model="partially_coherent", source_points=8)
    scene = draw_scene(cells_factory([1.6]), TRENCH, MIC, render)
    model = ForwardModel(MIC, render, Camera())
    fast = model.render_clean(scene, cache=False)
    np.testing.assert_array_equal(
        fast, ForwardModel(MIC, render, Camera()).render_clean(scene.replace_media(scene.media))
    )


def test_same_seed_same_bits_on_the_static_path(cells_factory):
    scene = draw_scene(cells_factory([1.6, 4.4]), TRENCH, MIC, RS)
    render = dataclasses.replace(RS, noise_model="camera")
    images = []
    for _ in range(2):
        model = ForwardModel(MIC, render, Camera())
        model.render(scene, np.random.default_rng(0), cache=False)  # composed, then static
        images.append(model.render(scene, np.random.default_rng(3), cache=False))
        assert model._static_plan(scene) is not None
    np.testing.assert_array_equal(images[0], images[1])
    assert images[0].dtype == np.uint16


def test_a_single_frame_stays_on_the_composed_path(cells_factory):
    """The static layers cost two transforms: built from a model's second frame of a
    geometry on, or at once where a model sharing the cache has them."""
    model = ForwardModel(MIC, RS, Camera())
    frames = [draw_scene(cells_factory([y]), TRENCH, MIC, RS) for y in (1.5, 2.0, 2.5)]
    model.render_clean(frames[0], cache=False)
    assert model.cache_info["misses"] == 0  # composed: the cache is not touched
    model.render_clean(frames[1], cache=False)
    assert model.cache_info["misses"] == 2  # open and device convolved once ...
    model.render_clean(frames[2], cache=False)
    assert model.cache_info["misses"] == 2  # ... and reused
    brighter = model.with_render(dataclasses.replace(RS, cell_intensity=1900.0))
    brighter.render_clean(frames[0], cache=False)
    assert brighter._static_plan(frames[0]) is not None
    assert model.cache_info["misses"] == 2


def test_the_pipeline_renders_trench_frames_on_the_static_path():
    """``iter_render``'s scenes (default settings) carry the static layers; with a media
    texture they do not, and both render as the composed image does."""
    from napari_symbac.pipeline import draw_frame
    from napari_symbac.settings import PipelineSettings, SimulationSettings
    from napari_symbac.sim import simulate

    settings = PipelineSettings(
        simulation=SimulationSettings(n_frames=4, seed=2), render=dataclasses.replace(RS)
    )
    simulation = simulate(settings.simulation)
    textured = dataclasses.replace(
        settings, render=dataclasses.replace(RS, texture_amplitude=0.2)
    )
    model = ForwardModel(settings.microscope, settings.render, settings.camera)
    for index in (1, 3):
        scene = draw_frame(simulation, settings, index)
        assert static_layers(scene) is not None
        _close(_fast(model, scene), _composed(model, scene))
        assert static_layers(draw_frame(simulation, textured, index)) is None
