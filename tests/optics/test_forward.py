"""The forward model: composition (eq. 3, 15), caching, backends, noise (eq. 17)."""

from __future__ import annotations

import dataclasses
import importlib.util

import numpy as np
import pytest

from napari_symbac.optics import ForwardModel, Stage, block_average, texture_stage
from napari_symbac.optics.psf import airy_psf, born_wolf_psf_3d
from napari_symbac.scene import draw_scene
from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry

MIC = Microscope()
RS = RenderSettings(psf_radius_px=30, ring_contrast=1.0, noise_model="none")
WIDE = TrenchGeometry(length_um=12.0, width_um=4.0, depth_um=1.2, margin_um=2.0)


@pytest.fixture
def scene(cells_factory):
    return draw_scene(cells_factory([2.0, 5.5], x_um=2.0, width_um=0.9), WIDE, MIC, RS)


def test_flat_regions_render_at_their_intensities(scene):
    model = ForwardModel(MIC, RS, Camera())
    image = model.render_clean(scene)
    assert image.dtype == np.float32
    assert image.shape == scene.camera_shape
    ps = MIC.pixel_size_um
    # Device far from the trench, empty media far from cells and walls.
    assert image[round(8 / ps), 2] == pytest.approx(RS.device_intensity, rel=0.01)
    assert image[round(12.5 / ps), round(4.0 / ps)] == pytest.approx(RS.media_intensity, rel=0.01)
    # Phase contrast: cells darker than media, with a bright halo beside them.
    cell_px = image[round(4.0 / ps), round(4.0 / ps)]
    assert cell_px < RS.media_intensity
    row = image[round(4.0 / ps), round(4.0 / ps) : round(5.9 / ps)]
    assert row.max() > RS.media_intensity * 1.02


def test_linear_in_intensities_and_cached(scene):
    model = ForwardModel(MIC, RS)
    base = model.render_clean(scene)
    misses = model.cache_info["misses"]
    assert misses == 3
    new = dataclasses.replace(RS, cell_intensity=500.0, media_intensity=3000.0)
    tuned = model.with_render(new)
    image = tuned.render_clean(scene)
    assert tuned.cache_info["misses"] == misses  # no new convolution
    fresh = ForwardModel(MIC, new).render_clean(scene)
    np.testing.assert_allclose(image, fresh, rtol=1e-6, atol=1e-3)
    comps = model.components(scene)
    combo = 500.0 * comps["cells"] + 3000.0 * comps["media"] + RS.device_intensity * comps["device"]
    np.testing.assert_allclose(image, combo, rtol=1e-6)
    assert not np.allclose(base, image)
    # A kernel change does convolve again.
    model.with_render(dataclasses.replace(RS, apodisation_sigma_um=0.9)).render_clean(scene)
    assert model.cache_info["misses"] == misses + 3


def test_same_seed_is_bit_identical(scene):
    model = ForwardModel(MIC, dataclasses.replace(RS, noise_model="camera"))
    a = model.render(scene, np.random.default_rng(7))
    b = model.render(scene, np.random.default_rng(7))
    c = model.render(scene, np.random.default_rng(8))
    assert a.dtype == np.uint16
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    none = ForwardModel(MIC, RS, Camera(baseline_adu=100)).render(scene, np.random.default_rng(0))
    np.testing.assert_array_equal(none, np.rint(ForwardModel(MIC, RS).render_clean(scene) + 100))
    with pytest.raises(ValueError, match="Generator"):
        model.render(scene, 7)


def test_fluorescence_conserves_flux(scene):
    mic = dataclasses.replace(MIC, modality="fluorescence")
    rs = dataclasses.replace(RS, cell_intensity=1000.0, media_intensity=0.0, device_intensity=0.0)
    image = ForwardModel(mic, rs).render_clean(scene)
    truth = 1000.0 * block_average(scene.interior(scene.cells), scene.upsample)
    assert image.sum() == pytest.approx(truth.sum(), rel=0.01)
    assert image.max() < truth.max()  # blurred


def test_sum_over_z_matches_2d_for_a_z_invariant_psf(scene):
    """Eq. 16 with identical planes equals the 2-D convolution of the projection."""
    model = ForwardModel(dataclasses.replace(MIC, modality="fluorescence"), RS)
    z = 4
    volume = np.repeat(scene.cells[None] / z, z, axis=0)
    psf = np.repeat(airy_psf(30, scene.pixel_size_um, 0.65, 1.45)[None], z, axis=0)
    three_d = model.render_fluorescence_3d(volume, psf)
    two_d = model.components(scene)["cells"]
    np.testing.assert_allclose(three_d, two_d, atol=1e-5)
    # A real 3-D PSF blurs out-of-focus planes more.
    bw = born_wolf_psf_3d(30, scene.pixel_size_um, np.linspace(-0.6, 0.6, z), 0.65, 1.45, 1.518)
    blurred = model.render_fluorescence_3d(volume, bw)
    assert blurred.max() < two_d.max()


def test_extra_stage_and_texture(scene):
    texture = np.ones(scene.camera_shape, np.float32)
    model = ForwardModel(MIC, RS, extra_stages=[texture_stage(texture, 0.1)])
    plain = ForwardModel(MIC, RS).render_clean(scene)
    np.testing.assert_allclose(model.render_clean(scene), plain * 1.1, rtol=1e-6)
    assert [s.name for s in model.stages] == ["psf", "resample", "intensity", "texture", "camera"]
    with pytest.raises(ValueError, match="apply"):
        ForwardModel(MIC, RS, extra_stages=[Stage("broken", False)])


def test_mismatched_scene_and_bad_settings(scene):
    with pytest.raises(ValueError, match="upsample"):
        ForwardModel(MIC, dataclasses.replace(RS, upsample=4)).render_clean(scene)
    with pytest.raises(ValueError, match="border"):
        ForwardModel(MIC, dataclasses.replace(RS, psf_radius_px=40)).render_clean(scene)
    with pytest.raises(ValueError, match=r"eq\. 13"):
        ForwardModel(MIC, dataclasses.replace(RS, apodisation_sigma_um=0.1))


def test_torch_backend_matches_scipy_or_says_what_to_install(scene):
    if importlib.util.find_spec("torch") is None:
        with pytest.raises(ValueError, match="torch"):
            ForwardModel(MIC, RS, backend="torch")
        return
    a = ForwardModel(MIC, RS).render_clean(scene)
    b = ForwardModel(MIC, RS, backend="torch").render_clean(scene)
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=0.05)


def test_unknown_backend():
    with pytest.raises(ValueError, match="unknown convolution backend"):
        ForwardModel(MIC, RS, backend="opencl")


@pytest.mark.parametrize("upsample", [1, 2, 3])
def test_fused_convolve_resample_matches_convolve_then_average(upsample):
    from napari_symbac.optics.backends import ScipyBackend

    rng = np.random.default_rng(3)
    kernel = rng.random((21, 21)).astype(np.float32)
    kernel /= kernel.sum()
    images = rng.random((3, 20 + 6 * upsample * 5, 20 + 6 * upsample * 3)).astype(np.float32)
    backend = ScipyBackend()
    expected = block_average(backend.convolve_valid(images, kernel), upsample)
    got = backend.convolve_resample(images, kernel, upsample)
    assert got.shape == expected.shape
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)
    weights = np.array([700.0, 4200.0, 950.0])
    combined = backend.convolve_resample(images, kernel, upsample, weights=weights)
    np.testing.assert_allclose(combined, np.tensordot(weights, expected, axes=1), rtol=1e-5)


@pytest.mark.parametrize("upsample", [1, 2, 3])
def test_fused_slab_sum_matches_convolve_sum_then_average(upsample):
    """eq. 16's slabs, each through its own kernel, summed: the fused form (one transform
    per slab, one inverse at camera resolution) equals the unfused one, and a model's
    depth render (the scipy backend) goes through it."""
    from napari_symbac.optics.backends import ScipyBackend

    rng = np.random.default_rng(4)
    kernels = rng.random((5, 21, 21)).astype(np.float32)
    kernels /= kernels.sum(axis=(1, 2), keepdims=True)
    layers = rng.random((5, 20 + 6 * upsample * 5, 20 + 6 * upsample * 3)).astype(np.float32)
    backend = ScipyBackend()
    expected = block_average(backend.convolve_valid(layers, kernels, sum_planes=True), upsample)
    got = backend.convolve_resample_sum(layers, kernels, upsample)
    assert got.shape == expected.shape
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-5)
    one = backend.convolve_resample_sum(layers[:1], kernels[:1], upsample)
    np.testing.assert_allclose(one, backend.convolve_resample(layers[:1], kernels[0], upsample)[0],
                               rtol=1e-5, atol=1e-6)  # fmt: skip
    model = ForwardModel(MIC, RS)
    np.testing.assert_allclose(model.convolve_depth(layers, kernels, upsample), got)
    with pytest.raises(ValueError, match="is not a multiple of"):
        backend.convolve_resample_sum(layers[:, :-1], kernels, 2)


def test_kernel_spectra_are_kept_by_count_and_bytes_but_the_last_eight_always(monkeypatch):
    """A scene fit's dozens of patch sizes stay cached; large frame spectra are held to a
    byte budget, but never to fewer than the last 8 (the bound before)."""
    from napari_symbac.optics import backends

    backend = backends.ScipyBackend()
    for i in range(200):
        backend._cached(("patch", i), lambda: np.zeros(4, np.complex64))
    assert list(backend._kernel_ffts) == [("patch", i) for i in range(72, 200)]
    monkeypatch.setattr(backends, "_MAX_SPECTRA_BYTES", 1000)
    for i in range(10):  # 800 bytes each: more than the budget beside any other
        backend._cached(("frame", i), lambda: np.zeros(100, np.complex64))
    assert list(backend._kernel_ffts) == [("frame", i) for i in range(2, 10)]


@pytest.mark.parametrize("noise_model", ["none", "camera", "gaussian"])
def test_fast_path_equals_cached_path(scene, cells_factory, noise_model):
    """``cache=False`` (static layers once, then the cells) is the cached render up to
    float32 rounding."""
    settings = dataclasses.replace(RS, noise_model=noise_model)
    model = ForwardModel(MIC, settings, Camera())
    cached = model.render_clean(scene)
    misses = model.cache_info["misses"]
    fast = model.render_clean(scene, cache=False)
    assert model.cache_info["misses"] == misses  # a first frame: composed, no cache traffic
    # from the second frame of a geometry on, the static open and device layers are
    # convolved once and cached ...
    other = draw_scene(cells_factory([3.0], x_um=2.0, width_um=0.9), WIDE, MIC, RS)
    model.render_clean(other, cache=False)
    assert model.cache_info["misses"] == misses + 2
    # ... so further frames of the same geometry neither fill nor miss the cache
    np.testing.assert_allclose(model.render_clean(scene, cache=False), fast, rtol=1e-5, atol=5e-3)
    assert model.cache_info["misses"] == misses + 2
    assert fast.dtype == np.float32
    assert fast.shape == cached.shape
    np.testing.assert_allclose(fast, cached, rtol=1e-5, atol=5e-3)
    a = model.render(scene, np.random.default_rng(7))
    b = model.render(scene, np.random.default_rng(7), cache=False)
    diff = np.abs(a.astype(np.int64) - b.astype(np.int64))
    if noise_model == "camera":
        # A rounding-level change of the Poisson mean can flip a draw by one electron
        # (``sensitivity`` ADU) at a rare pixel; the number and order of draws are unchanged.
        assert diff.max() <= np.ceil(Camera().sensitivity_adu_per_e) + 1
        assert (diff > 1).mean() < 1e-3
    else:
        assert diff.max() <= 1
    # Same seed -> same bits, on the fast path too.
    c = model.render(scene, np.random.default_rng(7), cache=False)
    np.testing.assert_array_equal(b, c)


def test_fast_path_with_extra_stage_and_without_fused_backend(scene):
    stage = Stage("gain", False, {"g": 2}, lambda image, _scene: image * 2)
    model = ForwardModel(MIC, RS, extra_stages=[stage])
    np.testing.assert_allclose(
        model.render_clean(scene, cache=False), model.render_clean(scene), rtol=1e-5, atol=5e-3
    )

    class Plain:  # a backend with convolve_valid only (like torch / cupy)
        name = "plain"

        def __init__(self):
            from napari_symbac.optics.backends import ScipyBackend

            self._inner = ScipyBackend()

        def convolve_valid(self, images, kernel, *, sum_planes=False):
            return self._inner.convolve_valid(images, kernel, sum_planes=sum_planes)

    plain = ForwardModel(MIC, RS, backend=Plain())
    np.testing.assert_allclose(
        plain.render_clean(scene, cache=False), model.render_clean(scene) / 2, rtol=1e-5, atol=5e-3
    )
    np.testing.assert_allclose(
        plain.render_clean(scene), model.render_clean(scene) / 2, rtol=1e-5, atol=5e-3
    )
