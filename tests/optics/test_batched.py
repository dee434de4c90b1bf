"""The batched torch path (optics/batched.py) against the CPU forward model, on torch's CPU."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
import torch

from napari_symbac.optics import ForwardModel, texture_stage
from napari_symbac.optics.batched import BatchedRenderer, render_scenes, resolve_backend
from napari_symbac.optics.camera import apply_camera_noise, apply_gaussian_noise
from napari_symbac.optics.static import static_layers
from napari_symbac.pipeline import iter_scenes, render_simulation
from napari_symbac.settings import (
    AgarPadGeometry,
    Camera,
    Microscope,
    PipelineSettings,
    RenderSettings,
    SimulationSettings,
)
from napari_symbac.sim import simulate

CLEAN = RenderSettings(noise_model="none")
SEPARATE = RenderSettings(noise_model="none", cell_phase_adu=300.0, device_phase_adu=120.0)
#: torch devices the device tests run on: the CPU everywhere, and a CUDA GPU where torch
#: sees one (the same assertions; CI has none)
DEVICES = ["cpu", *(["cuda"] if torch.cuda.is_available() else [])]


@pytest.fixture(scope="module")
def trench():
    settings = SimulationSettings(n_frames=10, seed=1)
    return settings, simulate(settings)


@pytest.fixture(scope="module")
def field():
    settings = SimulationSettings(
        geometry="agar_pad", n_frames=24, agar_pad=AgarPadGeometry(16.0, 14.0), seed=3
    )
    return settings, simulate(settings)


def _scenes(sim_pair, render, microscope=None, last=5):
    settings, simulation = sim_pair
    pipeline = PipelineSettings(
        simulation=settings, render=render, microscope=microscope or Microscope()
    )
    return pipeline, list(iter_scenes(simulation, pipeline))[-last:]


def _relative_difference(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / np.ptp(b))


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("geometry", ["trench", "field", "trench-plain"])
@pytest.mark.parametrize(
    ("render", "modality"),
    [(CLEAN, "phase"), (SEPARATE, "phase"), (CLEAN, "fluorescence"), (CLEAN, "brightfield")],
    ids=["phase", "separate-ring", "fluorescence", "brightfield"],
)
def test_noise_free_batch_equals_cpu_path(geometry, render, modality, device, request):
    """Drawn scenes take the static-layer path (cells alone on the device, the open and
    device layers' image once); "plain" copies of them, which do not carry their open
    fraction, the composed path (eq. 3 composed on the host, one plane). Bright field's
    lens term (a second kernel) is drawn alike by every path."""
    if modality == "fluorescence":
        render = dataclasses.replace(
            render, cell_intensity=2000.0, media_intensity=150.0, device_intensity=100.0
        )
    if modality == "brightfield":
        render = dataclasses.replace(
            render,
            cell_intensity=2500.0,
            media_intensity=2600.0,
            device_intensity=2300.0,
            defocus_contrast_um2=0.015,
        )
    microscope = Microscope(modality=modality)
    sim_pair = request.getfixturevalue(geometry.partition("-")[0])
    pipeline, scenes = _scenes(sim_pair, render, microscope)
    if geometry.endswith("plain"):
        scenes = [dataclasses.replace(scene) for scene in scenes]
    assert (static_layers(scenes[0]) is None) == geometry.endswith("plain")
    model = ForwardModel(pipeline.microscope, pipeline.render, pipeline.camera)
    expected = np.stack([model.render_clean(scene, cache=False) for scene in scenes])
    got = BatchedRenderer(model, device, batch_frames=3).render_clean(scenes)
    assert got.dtype == np.float32
    assert got.shape == expected.shape == (len(scenes), *scenes[0].camera_shape)
    assert _relative_difference(got, expected) < 1e-5
    # and the cached per-component path, which the live tuning uses
    cached = np.stack([model.render_clean(scene) for scene in scenes])
    assert _relative_difference(got, cached) < 1e-5
    # one frame with a model that has not seen its geometry: composed, as on the CPU
    fresh = ForwardModel(pipeline.microscope, pipeline.render, pipeline.camera)
    one = BatchedRenderer(fresh, device).render_clean(scenes[:1])
    assert _relative_difference(one, expected[:1]) < 1e-5


def _noise_statistics(counts: np.ndarray, clean: np.ndarray, baseline: float, edges):
    """Mean and variance of ``counts - baseline - clean`` per bin of the clean intensity."""
    level = np.broadcast_to(clean, counts.shape)
    residual = counts.astype(np.float64) - baseline - level
    stats = []
    for low, high in itertools.pairwise(edges):
        inside = (level >= low) & (level < high)
        values = residual[inside]
        stats.append((values.mean(), values.var(), level[inside].mean(), values.size))
    return np.array(stats)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize(
    ("noise_model", "dark_noise_e"), [("camera", 8.0), ("camera", 1.0), ("gaussian", 8.0)]
)
def test_noise_has_the_cpu_paths_mean_and_variance_per_level(
    trench, noise_model, dark_noise_e, device
):
    """Per level of the clean image: mean and variance as the CPU path's and eq. 17's.

    With 8 e- of read noise every pixel takes the single Gaussian draw; with 1 e- the
    pixels below ~397 e- (the darker half of the frame) draw exact Poisson counts.
    """
    camera = Camera(baseline_adu=100.0, sensitivity_adu_per_e=2.9, dark_noise_e=dark_noise_e)
    render = dataclasses.replace(CLEAN, noise_model=noise_model, gaussian_noise_sd_adu=15.0)
    pipeline, scenes = _scenes(trench, render, last=1)
    model = ForwardModel(pipeline.microscope, render, camera)
    clean = model.render_clean(scenes[0], cache=False)
    draws = 24
    ours = BatchedRenderer(model, device).render(scenes * draws, np.random.default_rng(5))
    rng = np.random.default_rng(5)
    if noise_model == "camera":
        cpu = np.stack([apply_camera_noise(clean, camera, rng) for _ in range(draws)])
    else:
        cpu = np.stack([apply_gaussian_noise(clean, camera, 15.0, rng) for _ in range(draws)])
    assert ours.dtype == np.uint16
    assert ours.shape == cpu.shape
    edges = np.quantile(clean, np.linspace(0, 1, 7))
    edges[-1] += 1.0
    stats = _noise_statistics(ours, clean, camera.baseline_adu, edges)
    theirs = _noise_statistics(cpu, clean, camera.baseline_adu, edges)
    for (m1, v1, level, n), (m2, v2, _, _) in zip(stats, theirs):
        # means: both at the clean level (eq. 17 is unbiased), within 5 standard errors
        assert abs(m1 - m2) < 5 * np.sqrt((v1 + v2) / n)
        assert abs(m1) < 5 * np.sqrt(v1 / n)
        # variances: the photon-transfer line (+ 1/12 of rounding), within 4 %
        if noise_model == "camera":
            s = camera.sensitivity_adu_per_e
            theory = s * level + (s * camera.dark_noise_e) ** 2 + 1 / 12
        else:
            theory = 15.0**2 + 1 / 12
        assert v1 == pytest.approx(v2, rel=0.04)
        assert v1 == pytest.approx(theory, rel=0.04)


def _same_but_for_transform_rounding(a: np.ndarray, b: np.ndarray) -> None:
    """The same noise streams in another batch size: FFT libraries may round a batch of
    transforms differently (seen with MKL on a 16-core host and with cuFFT), which moves
    a count by 1 where the clean value lies at a rounding boundary."""
    difference = np.abs(a.astype(int) - b.astype(int))
    assert difference.max() <= 1
    assert np.count_nonzero(difference) <= 1e-3 * a.size


@pytest.mark.parametrize("device", DEVICES)
def test_same_seed_same_images_whatever_the_batch_size(trench, device):
    """Same call, same bits; the noise of a frame does not depend on the batch it is in."""
    render = dataclasses.replace(CLEAN, noise_model="camera")
    pipeline, scenes = _scenes(trench, render)
    model = ForwardModel(pipeline.microscope, render, pipeline.camera)
    a = BatchedRenderer(model, device).render(scenes, np.random.default_rng(11))
    np.testing.assert_array_equal(
        a, BatchedRenderer(model, device).render(scenes, np.random.default_rng(11))
    )
    b = BatchedRenderer(model, device, batch_frames=2).render(scenes, np.random.default_rng(11))
    _same_but_for_transform_rounding(a, b)
    # a batch of 10 frames is filled on the host by several threads
    many = scenes * 2
    c1 = BatchedRenderer(model, device, batch_frames=10).render(many, np.random.default_rng(3))
    c2 = BatchedRenderer(model, device, batch_frames=1).render(many, np.random.default_rng(3))
    _same_but_for_transform_rounding(c1, c2)
    c = BatchedRenderer(model, device).render(scenes, np.random.default_rng(12))
    assert np.abs(a.astype(int) - c.astype(int)).max() > 1
    # each frame its own stream: two frames of one scene get different noise
    twice = BatchedRenderer(model, device).render(scenes[:1] * 2, np.random.default_rng(11))
    assert not np.array_equal(twice[0], twice[1])
    # noise model "none": the rounded clean image plus the baseline, as on the CPU
    exact = BatchedRenderer(model.with_render(CLEAN), device).render(
        scenes, np.random.default_rng(0)
    )
    cpu = np.stack([model.with_render(CLEAN).render(s, np.random.default_rng(0)) for s in scenes])
    assert np.abs(exact.astype(int) - cpu.astype(int)).max() <= 1


@pytest.mark.parametrize("device", DEVICES)
def test_clipping_at_the_bit_depth(trench, device):
    camera = Camera(bit_depth=8, baseline_adu=100.0)
    render = dataclasses.replace(CLEAN, noise_model="camera")
    pipeline, scenes = _scenes(trench, render, last=2)
    model = ForwardModel(pipeline.microscope, render, camera)
    images = BatchedRenderer(model, device).render(scenes, np.random.default_rng(0))
    assert images.max() == 255  # media at ~1000 ADU saturates an 8-bit camera
    assert images.min() >= 0


@pytest.mark.parametrize("device", DEVICES)
def test_a_clip_of_the_recorded_image_is_drawn_as_on_the_cpu(trench, device):
    """The ``saturation`` stage `fit` writes for a recording clipped at 0 by a background
    subtraction (ColiCoords' fluorescence; `export --backend torch` refused it): applied
    to the finished frames, the same images as the unclipped ones clipped, with the
    recording's spike at the level."""
    from napari_symbac.diagnose.effects.saturation import stage as clip

    render = dataclasses.replace(CLEAN, noise_model="camera")
    pipeline, scenes = _scenes(trench, render, last=3)
    plain = ForwardModel(pipeline.microscope, render, Camera())
    unclipped = BatchedRenderer(plain, device).render(scenes, np.random.default_rng(5))
    level = int(np.median(unclipped))
    stage = clip({"clip_level_adu": level, "high": False})
    clipped_model = ForwardModel(pipeline.microscope, render, Camera(), extra_stages=[stage])
    clipped = BatchedRenderer(clipped_model, device).render(scenes, np.random.default_rng(5))
    assert clipped.dtype == np.uint16
    np.testing.assert_array_equal(clipped, np.maximum(unclipped, level))
    assert (clipped == level).mean() > 0.3  # the spike
    assert not np.array_equal(clipped, unclipped)


def test_refuses_stages_it_cannot_run_on_the_device(trench):
    _, scenes = _scenes(trench, CLEAN, last=1)
    coherent = dataclasses.replace(CLEAN, phase_model="partially_coherent")
    with pytest.raises(ValueError, match=r"'phase_image' stage .* --backend scipy"):
        BatchedRenderer(ForwardModel(Microscope(), coherent), "cpu")
    texture = texture_stage(np.zeros(scenes[0].camera_shape), 0.1)
    textured = ForwardModel(Microscope(), CLEAN, extra_stages=[texture])
    with pytest.raises(ValueError, match=r"'texture' stage .* --backend scipy"):
        BatchedRenderer(textured, "cpu")
    model = ForwardModel(Microscope(), dataclasses.replace(CLEAN, upsample=4))
    with pytest.raises(ValueError, match="upsample"):
        BatchedRenderer(model, "cpu").render_clean(scenes)
    with pytest.raises(ValueError, match="Generator"):
        BatchedRenderer(ForwardModel(Microscope(), CLEAN), "cpu").render(scenes, 3)
    with pytest.raises(ValueError, match="batch_frames"):
        BatchedRenderer(ForwardModel(Microscope(), CLEAN), "cpu", batch_frames=0)


def test_resolve_backend():
    assert resolve_backend("scipy") == "scipy"
    assert resolve_backend("torch", "cpu") == "torch:cpu"
    assert resolve_backend("torch:cpu") == "torch:cpu"
    expected = "torch:cuda" if torch.cuda.is_available() else "torch:cpu"
    assert resolve_backend("torch") == expected
    assert resolve_backend("torch", "auto") == expected
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="sees no CUDA GPU"):
            resolve_backend("torch", "cuda")
    with pytest.raises(ValueError, match="unknown render backend"):
        resolve_backend("opencl")
    with pytest.raises(ValueError, match="torch backend only"):
        resolve_backend("scipy", "cpu")
    with pytest.raises(ValueError, match="unknown torch device"):
        resolve_backend("torch", "tpu")


def test_render_simulation_on_torch(trench):
    settings, simulation = trench
    pipeline = PipelineSettings(simulation=settings, render=CLEAN)
    cpu = render_simulation(simulation, pipeline)
    device = render_simulation(simulation, pipeline, backend="torch:cpu")
    np.testing.assert_array_equal(device.labels, cpu.labels)
    np.testing.assert_array_equal(device.semantic, cpu.semantic)
    assert np.abs(device.images.astype(int) - cpu.images.astype(int)).max() <= 1
    # render_scenes keeps the order of an iterable consumed batch by batch
    model = ForwardModel(pipeline.microscope, pipeline.render, pipeline.camera)
    scenes = list(iter_scenes(simulation, pipeline))
    renderer = BatchedRenderer(model, "cpu", batch_frames=4)
    assert renderer.frames_per_batch(scenes[0]) == 4
    pairs = list(render_scenes(model, iter(scenes), np.random.default_rng(0), backend="torch:cpu"))
    assert [id(scene) for scene, _ in pairs] == [id(scene) for scene in scenes]


def test_benchmark_functions_return_their_rows():
    """napari_symbac.bench.cases_gpu (``napari-symbac bench``, benchmarks/bench_gpu.py)."""
    from napari_symbac.bench import cases_gpu as bench

    row = bench.measure_batch("torch:cpu", 3, bench.TRENCH, threads=1)
    assert row["backend"] == "torch:cpu"
    assert row["threads"] == 1
    assert row["n_frames"] == 3
    assert row["seconds"] > 0
    assert row["frames_per_s"] == pytest.approx(3 / row["seconds"])
    rows = bench.compare(2, (24, 20), runs=[("scipy", None), ("torch:cpu", None)], repeats=1)
    assert [r["backend"] for r in rows] == ["scipy", "torch:cpu"]
    assert rows[0]["vs_scipy"] == 1.0
    assert rows[1]["vs_scipy"] == pytest.approx(rows[1]["frames_per_s"] / rows[0]["frames_per_s"])
    assert ("scipy", None) in bench.available()


def test_render_scenes_same_images_whatever_the_chunking(trench):
    render = dataclasses.replace(CLEAN, noise_model="camera")
    pipeline, scenes = _scenes(trench, render, last=7)
    model = ForwardModel(pipeline.microscope, render, pipeline.camera)

    def images(batch_frames):
        pairs = render_scenes(
            model,
            iter(scenes),
            np.random.default_rng(4),
            backend="torch:cpu",
            batch_frames=batch_frames,
        )
        return np.stack([image for _, image in pairs])

    np.testing.assert_array_equal(images(3), images(3))
    _same_but_for_transform_rounding(images(3), images(7))


#: depth-resolved fluorescence (eq. 16): the cells in 5 slabs, focus 0.2 um above the
#: cells' mid-plane
DEPTH = dataclasses.replace(
    CLEAN,
    depth_layers=5,
    focus_offset_um=0.2,
    cell_intensity=2000.0,
    media_intensity=150.0,
    device_intensity=100.0,
)
FLUORESCENCE = Microscope(modality="fluorescence")


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("geometry", ["trench", "field"])
@pytest.mark.parametrize("envelope", [0.0, 0.6], ids=["volume", "envelope"])
def test_depth_resolved_batch_equals_cpu_path(geometry, envelope, device, request):
    """The depth stage on the device: each slab of the stain through its own kernel,
    media and device through the 2-D one. A volume stain keeps the drawn scene's open
    fraction (static path: the cells' window only); an envelope stain is a copy that
    does not (composed path)."""
    render = dataclasses.replace(DEPTH, envelope_stain_fraction=envelope)
    pipeline, scenes = _scenes(request.getfixturevalue(geometry), render, FLUORESCENCE)
    assert scenes[0].depth_profile.shape == (5, *scenes[0].shape)
    model = ForwardModel(pipeline.microscope, pipeline.render, pipeline.camera)
    assert model.stages[0].name == "depth"
    renderer = BatchedRenderer(model, device, batch_frames=3)
    layout = renderer._layout(scenes[:3])
    assert (layout.static is not None) == (envelope == 0.0)
    assert len(layout.planes) == 6  # 5 slabs + the 2-D plane (media and device, or -I_m C)
    expected = np.stack([model.render_clean(scene, cache=False) for scene in scenes])
    got = renderer.render_clean(scenes)
    assert got.dtype == np.float32
    assert got.shape == expected.shape == (len(scenes), *scenes[0].camera_shape)
    assert _relative_difference(got, expected) < 1e-5
    cached = np.stack([model.render_clean(scene) for scene in scenes])
    assert _relative_difference(got, cached) < 1e-5
    # the 2-D projection differs by far more: the depth stage did run
    flat = ForwardModel(FLUORESCENCE, dataclasses.replace(render, depth_layers=0))
    assert _relative_difference(got, BatchedRenderer(flat, device).render_clean(scenes)) > 1e-3
    # one frame with a model that has not seen its geometry: composed
    fresh = ForwardModel(pipeline.microscope, pipeline.render, pipeline.camera)
    one = BatchedRenderer(fresh, device).render_clean(scenes[:1])
    assert _relative_difference(one, expected[:1]) < 1e-5


@pytest.mark.parametrize("device", DEVICES)
def test_depth_resolved_noise_same_seed_same_images_whatever_the_batch_size(trench, device):
    render = dataclasses.replace(DEPTH, noise_model="camera")
    pipeline, scenes = _scenes(trench, render, FLUORESCENCE)
    model = ForwardModel(pipeline.microscope, render, pipeline.camera)
    a = BatchedRenderer(model, device).render(scenes, np.random.default_rng(11))
    np.testing.assert_array_equal(
        a, BatchedRenderer(model, device).render(scenes, np.random.default_rng(11))
    )
    for size in (1, 2):
        b = BatchedRenderer(model, device, batch_frames=size).render(
            scenes, np.random.default_rng(11)
        )
        _same_but_for_transform_rounding(a, b)
    c = BatchedRenderer(model, device).render(scenes, np.random.default_rng(12))
    assert np.abs(a.astype(int) - c.astype(int)).max() > 1
    # about the clean image plus the baseline: each frame's mean residual within 5
    # standard errors of 0 (the noise is unbiased), its spread the camera's noise
    clean = np.stack([model.render_clean(scene, cache=False) for scene in scenes])
    residual = a.astype(np.float64) - pipeline.camera.baseline_adu - clean
    pixels = residual[0].size
    assert np.all(np.abs(residual.mean(axis=(1, 2))) < 5 * residual.std() / np.sqrt(pixels))
    assert 1.0 < residual.std() < 0.5 * clean.std()


def test_depth_resolved_batch_refuses_scenes_without_a_profile_or_of_two_depths(trench):
    pipeline, scenes = _scenes(trench, DEPTH, FLUORESCENCE, last=2)
    renderer = BatchedRenderer(ForwardModel(pipeline.microscope, pipeline.render), "cpu")
    unstained = dataclasses.replace(scenes[0])  # a copy without the depth profile
    with pytest.raises(ValueError, match="no depth profile of as many slabs: stain it"):
        renderer.render_clean([unstained])
    deeper = dataclasses.replace(scenes[1], depth_um=scenes[1].depth_um + 0.2)
    deeper = deeper.with_depth_profile(scenes[1].depth_profile)
    with pytest.raises(ValueError, match="scenes of one depth"):
        renderer.render_clean([scenes[0], deeper])
