"""The camera from the data: censored pixels and photon transfer (eq. 17-19)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import tifffile
from scipy import ndimage

from napari_symbac.fit.camera_estimate import (
    MIN_UNRESOLVED_DARK_NOISE_E,
    censored_pixels,
    estimate_camera,
    image_bit_depth,
    with_unresolved_dark_noise,
)
from napari_symbac.optics import ForwardModel
from napari_symbac.optics.camera import apply_camera_noise
from napari_symbac.settings import Camera

CAMERAS = [
    Camera(),  # 2.9 ADU/e-, 8 e- read noise, baseline 100
    Camera(baseline_adu=500.0, sensitivity_adu_per_e=0.5, dark_noise_e=3.0),
    Camera(baseline_adu=100.0, sensitivity_adu_per_e=5.0, dark_noise_e=1.5, bit_depth=12),
]


def _smooth_signal(shape=(256, 256), low=200.0, high=3200.0) -> np.ndarray:
    """A smooth landscape of signal levels (ADU above the baseline)."""
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    return low + (high - low) * (0.5 + 0.5 * np.sin(xx / 40.0) * np.cos(yy / 50.0))


# --------------------------------------------------------------------------------------
# censored_pixels
# --------------------------------------------------------------------------------------


def test_censored_marks_the_digitiser_maximum():
    image = np.full((32, 32), 1000, np.uint16)
    image[:4] = 65535
    image[10, 10] = 2000
    censored = censored_pixels(image)
    assert censored[:4].all()
    assert censored.sum() == 4 * 32


def test_censored_finds_a_saturation_spike_below_the_file_maximum():
    rng = np.random.default_rng(0)
    image = np.clip(rng.normal(3000, 600, (64, 64)), 0, 4095).astype(np.uint16)
    assert (image == 4095).mean() > 0.01  # a 12-bit camera in a 16-bit file
    censored = censored_pixels(image)
    assert np.array_equal(censored, image == 4095)
    # the camera's own bit depth says the same without the histogram
    assert np.array_equal(censored_pixels(image, Camera(bit_depth=12)), image == 4095)


def test_censored_marks_zeros_of_background_subtraction():
    rng = np.random.default_rng(1)
    image = np.clip(rng.normal(20, 30, (64, 64)), 0, None)  # float, ~25 % clipped at 0
    censored = censored_pixels(image)
    assert np.array_equal(censored, image == 0)
    assert 0.2 < censored.mean() < 0.3


def test_censored_leaves_a_smooth_unclipped_image_alone():
    rng = np.random.default_rng(2)
    image = apply_camera_noise(_smooth_signal((64, 64)), Camera(), rng)
    assert not censored_pixels(image).any()


def test_censored_real_colicoords_fields_match_their_readme(real_data_dir):
    root = real_data_dir / "colicoords" / "test_data" / "ds1"
    brightfield = tifffile.imread(root / "brightfield" / "00001.tif")
    fluorescence = tifffile.imread(root / "fluorescence" / "00001.tif")
    # README: brightfield 9-12 % clipped at 65535, fluorescence 17-19 % at 0
    bright = censored_pixels(brightfield)
    assert 0.08 < bright.mean() < 0.13
    assert np.all(brightfield[bright] == 65535)
    dark = censored_pixels(fluorescence)
    assert 0.16 < dark.mean() < 0.20
    assert np.all(fluorescence[dark] == 0)


# --------------------------------------------------------------------------------------
# estimate_camera
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("camera", CAMERAS, ids=["default", "low-gain", "12-bit"])
def test_gain_from_one_image_within_5_percent(camera):
    image = apply_camera_noise(_smooth_signal(), camera, np.random.default_rng(3))
    estimate = estimate_camera(image, camera=camera)
    assert estimate.camera.sensitivity_adu_per_e == pytest.approx(
        camera.sensitivity_adu_per_e, rel=0.05
    )
    assert estimate.sensitivity_se_adu_per_e < 0.03 * camera.sensitivity_adu_per_e
    assert estimate.offset_source == "camera settings"
    assert estimate.camera.baseline_adu == camera.baseline_adu
    assert estimate.camera.bit_depth == camera.bit_depth
    assert estimate.method == "high-pass"


@pytest.mark.parametrize("camera", CAMERAS, ids=["default", "low-gain", "12-bit"])
def test_dark_frames_give_offset_and_read_noise(camera):
    rng = np.random.default_rng(4)
    image = apply_camera_noise(_smooth_signal(), camera, rng)
    dark = apply_camera_noise(np.zeros((4, 64, 64)), camera, rng)
    estimate = estimate_camera(image, dark_frames=dark, bit_depth=camera.bit_depth)
    assert estimate.offset_source == "dark frames"
    assert estimate.method == "high-pass + dark frames"
    assert estimate.camera.baseline_adu == pytest.approx(camera.baseline_adu, abs=0.5)
    # read noise in ADU is measured directly; in electrons it carries the gain's error
    assert estimate.camera.dark_noise_e == pytest.approx(camera.dark_noise_e, rel=0.08)


def test_model_mean_uses_the_residual_and_the_trench_render(truth):
    """The fit's noise-free image: y - mu over a series of rendered trench frames."""
    model = ForwardModel(truth.microscope, truth.render, truth.camera)
    clean = model.render_clean(truth.scene).astype(np.float64) + truth.camera.baseline_adu
    frames = np.stack([model.render(truth.scene, np.random.default_rng(10 + i)) for i in range(8)])
    estimate = estimate_camera(frames, model_mean=np.broadcast_to(clean, frames.shape))
    assert estimate.method == "model residual"
    assert estimate.n_points == frames.size
    assert estimate.camera.sensitivity_adu_per_e == pytest.approx(2.9, rel=0.05)
    # the intercept is sigma_r^2 - K offset = (2.9 * 8)^2 - 2.9 * 100 = 248 ADU^2
    se = estimate.sensitivity_se_adu_per_e
    assert abs(estimate.camera.sensitivity_adu_per_e - 2.9) < 4 * se


def test_series_of_rendered_trench_frames_without_a_model(truth):
    # the estimate's spread over noise seeds is 3.5 % with 8 frames (18 % of seeds miss
    # 5 %), 1.9 % with 32: 5 % is then 2.6 standard deviations
    model = ForwardModel(truth.microscope, truth.render, truth.camera)
    frames = np.stack(
        [model.render(truth.scene, np.random.default_rng(20 + i)) for i in range(32)]
    )
    estimate = estimate_camera(frames, camera=truth.camera)
    assert estimate.camera.sensitivity_adu_per_e == pytest.approx(2.9, rel=0.05)
    assert estimate.n_points > 32 * 30 * 100


def test_valid_mask_and_censoring_keep_clipped_pixels_out():
    camera = Camera(bit_depth=12)
    signal = _smooth_signal(low=300.0, high=5000.0)  # the top is clipped at 4095
    image = apply_camera_noise(signal, camera, np.random.default_rng(5))
    assert (image == 4095).mean() > 0.05
    estimate = estimate_camera(image, camera=camera)
    assert estimate.camera.sensitivity_adu_per_e == pytest.approx(2.9, rel=0.05)
    half = np.zeros(image.shape, bool)
    half[:, :128] = True
    masked = estimate_camera(image, camera=camera, valid=half)
    assert masked.n_points < 0.6 * estimate.n_points


def test_correlated_noise_is_detected_and_said():
    """Noise shared between horizontal neighbours (as from interpolation) biases the
    single-image gain low; the lag-2 / lag-1 variance ratio shows it."""
    signal = _smooth_signal()
    white = apply_camera_noise(signal, Camera(), np.random.default_rng(11)).astype(float)
    noise = white - signal - 100.0
    shared = ndimage.correlate1d(noise, [0.3, 1.0, 0.3], axis=1) / np.sqrt(1.18)
    correlated = shared + signal + 100.0
    clean = estimate_camera(white, camera=Camera())
    assert abs(clean.neighbour_variance_ratio - 1) < 0.1
    assert "not white" not in clean.summary()
    biased = estimate_camera(correlated, camera=Camera())
    assert biased.camera.sensitivity_adu_per_e < 0.5 * 2.9  # the bias the ratio warns of
    assert biased.neighbour_variance_ratio > 2.0
    assert "the noise is not white" in biased.summary()
    model = estimate_camera(white, model_mean=signal + 100.0)
    assert np.isnan(model.neighbour_variance_ratio)


def test_the_measured_camera_note_says_correlated_noise_in_the_askers_words():
    """diagnose's note on a measured camera returns the neighbour ratio it measured (the
    command measured it a second time for its chi-square caution), and tells the dock's
    user of the Recording step, not of `napari-symbac fit --dark` (found as a user)."""
    from napari_symbac._widgets._recording import GUI_CAMERA_FIX
    from napari_symbac.fit.report import measured_camera_note

    signal = _smooth_signal()
    white = apply_camera_noise(signal, Camera(), np.random.default_rng(11)).astype(float)
    noise = white - signal - 100.0
    shared = ndimage.correlate1d(noise, [0.3, 1.0, 0.3], axis=1) / np.sqrt(1.18)
    correlated = shared + signal + 100.0
    camera = estimate_camera(correlated, camera=Camera()).camera
    note, ratio = measured_camera_note(correlated, camera)
    assert ratio == estimate_camera(correlated, camera=camera).neighbour_variance_ratio > 2
    assert "correlated between neighbours" in note
    assert note.endswith("`napari-symbac fit IMAGE --dark DARK.tif` writes to its settings.yaml")
    dock_note, _ = measured_camera_note(correlated, camera, give_camera=GUI_CAMERA_FIX)
    assert dock_note.endswith(GUI_CAMERA_FIX)
    assert "--dark" not in dock_note
    flat = np.full((32, 32), 500.0)
    note, ratio = measured_camera_note(flat, Camera())
    assert ratio is None
    assert "the image's own photon transfer" in note


def test_the_camera_of_a_recording_fit_starts_from(real_data_dir):
    """The camera Simulate and the fit take from a recording without one given: an
    8-bit colony's is 8 bits at its own offset; a flattened bright field (ColiCoords,
    ~65000 ADU, a tenth clipped) has no photon-transfer line, and draws its own pixel
    noise (found as a user: the built-in gain drew 158 ADU s.d. against its 28)."""
    from napari_symbac.fit.report import unmeasured_noise_adu
    from napari_symbac.fit.scene_fit import recording_camera
    from napari_symbac.io import read_image

    colony = np.asarray(read_image(real_data_dir / "omnipose" / "Sample000252.png").data)
    camera = recording_camera(colony)
    assert camera.bit_depth == 8
    assert 0 <= camera.baseline_adu <= np.quantile(colony, 0.001)
    field = tifffile.imread(
        real_data_dir / "colicoords" / "test_data" / "ds1" / "brightfield" / "00001.tif"
    )
    camera = recording_camera(field)
    noise_adu = unmeasured_noise_adu(camera)
    assert noise_adu is not None
    background = np.full((64, 64), float(np.median(field)) - camera.baseline_adu)
    drawn = apply_camera_noise(background, camera, np.random.default_rng(0)).astype(float)
    masks = tifffile.imread(
        real_data_dir / "colicoords/test_data/ds1/binary/00001_Probabilities_filtered.tif"
    )
    background_px = (masks == 0) & (field < field.max())
    real_sd = float(field[background_px].std())  # 27.9 ADU
    assert 0.5 * real_sd < drawn.std() < 1.5 * real_sd


def test_same_input_same_estimate():
    image = apply_camera_noise(_smooth_signal(), Camera(), np.random.default_rng(6))
    assert estimate_camera(image) == estimate_camera(image)


def test_offset_from_the_darkest_region_is_labelled():
    image = apply_camera_noise(_smooth_signal(low=0.0), Camera(), np.random.default_rng(7))
    estimate = estimate_camera(image)
    assert estimate.offset_source == "darkest region of the image"
    # the darkest region holds a little light: its level bounds the baseline (100) from
    # above, within 2 % of the image's signal range (3000 ADU)
    assert 100.0 <= estimate.camera.baseline_adu < 160.0


def test_rescaled_image_is_refused():
    image = apply_camera_noise(_smooth_signal(), Camera(), np.random.default_rng(8))
    flattened = 65535.0 - image.astype(float)  # variance now falls with the mean
    with pytest.raises(ValueError, match="not raw camera counts"):
        estimate_camera(flattened)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"valid": np.ones((5, 5), bool)}, "valid has shape"),
        ({"model_mean": np.ones((5, 5))}, "model_mean has shape"),
    ],
)
def test_bad_inputs_name_the_problem(kwargs, message):
    image = apply_camera_noise(_smooth_signal((64, 64)), Camera(), np.random.default_rng(9))
    with pytest.raises(ValueError, match=message):
        estimate_camera(image, **kwargs)
    with pytest.raises(ValueError, match="NaN"):
        estimate_camera(np.full((32, 32), np.nan))
    with pytest.raises(ValueError, match="usable pixels"):
        estimate_camera(image[:20, :20])


def test_real_colicoords_ds3_fluorescence(real_data_dir):
    """Four fluorescence frames with the camera offset kept (README of the data)."""
    stack = tifffile.imread(real_data_dir / "colicoords" / "test_data" / "ds3" / "flu.tif")
    estimate = estimate_camera(stack)
    assert not censored_pixels(stack).any()
    assert estimate.offset_source == "darkest region of the image"
    # the offset is kept: the darkest region sits far above zero, below the median
    assert 1000 < estimate.camera.baseline_adu < float(np.median(stack))
    gain = estimate.camera.sensitivity_adu_per_e
    assert estimate.sensitivity_se_adu_per_e < 0.05 * gain
    assert estimate.n_bins >= 10
    # its noise is correlated between neighbouring pixels (all ColiCoords fields are)
    assert estimate.neighbour_variance_ratio > 1.1
    assert "not white" in estimate.summary()
    # two halves of the series agree within their standard errors
    first, second = estimate_camera(stack[:2]), estimate_camera(stack[2:])
    difference = first.camera.sensitivity_adu_per_e - second.camera.sensitivity_adu_per_e
    combined = np.hypot(first.sensitivity_se_adu_per_e, second.sensitivity_se_adu_per_e)
    assert abs(difference) < 4 * combined


def test_a_kept_camera_offset_becomes_the_fits_baseline(real_data_dir):
    """ColiCoords ds3 kept its camera offset (every pixel above 1717 ADU): the 100 ADU
    guess would count 1650 ADU of offset as light and predict a background noise 4x the
    real one; the variance line's zero (about 1760 ADU) is the baseline instead."""
    from napari_symbac.fit import fit_scene
    from napari_symbac.settings import Microscope, RenderSettings

    stack = tifffile.imread(real_data_dir / "colicoords" / "test_data" / "ds3" / "flu.tif")
    frame = stack[3, 192:320, 192:320].astype(np.float64)
    microscope = Microscope(pixel_size_um=0.08, wavelength_um=0.53, modality="fluorescence")
    fit = fit_scene(frame, microscope, RenderSettings(), None, geometry="open",
                    max_iterations=3)  # fmt: skip
    assert 1700 < fit.camera.baseline_adu <= np.quantile(frame, 0.001)
    # the noise the fitted camera predicts on the background is the image's own
    background = frame < np.percentile(frame, 60)
    level = np.median(frame[background]) - fit.camera.baseline_adu
    predicted_sd = np.sqrt(fit.camera.sensitivity_adu_per_e * level)
    pairs = np.diff(frame, axis=1)[background[:, 1:] & background[:, :-1]]
    measured_sd = 1.4826 * np.median(np.abs(pairs - np.median(pairs))) / np.sqrt(2)
    assert predicted_sd == pytest.approx(measured_sd, rel=0.5)
    # its read noise, not resolved, is not 0 either: the image holds every level
    assert fit.camera.dark_noise_e == MIN_UNRESOLVED_DARK_NOISE_E


def _levels_used(image: np.ndarray) -> float:
    """The share of the ADU levels in the middle half of an image's values it holds."""
    low, high = np.percentile(image, (25, 75))
    inside = image[(image >= low) & (image <= high)]
    return np.unique(inside).size / (high - low + 1)


def test_an_unresolved_read_noise_is_drawn_at_half_an_electron():
    """Found as a user: ColiCoords ds3 measured as 19.2 ADU/e- with 0 e- read noise was
    drawn in steps of 19.2 ADU (7 % of the levels of a background holding all of them)."""
    signal = _smooth_signal(low=20.0, high=400.0)
    noiseless = Camera(baseline_adu=100.0, sensitivity_adu_per_e=19.2, dark_noise_e=0.0)
    # a camera with sub-electron read noise: its image holds the levels between electrons
    recording = apply_camera_noise(
        signal, dataclasses.replace(noiseless, dark_noise_e=0.3), np.random.default_rng(5)
    )
    assert _levels_used(recording) > 0.9
    drawn = with_unresolved_dark_noise(noiseless, recording)
    assert drawn.dark_noise_e == MIN_UNRESOLVED_DARK_NOISE_E
    assert _levels_used(apply_camera_noise(signal, noiseless, np.random.default_rng(6))) < 0.1
    assert _levels_used(apply_camera_noise(signal, drawn, np.random.default_rng(6))) > 0.9
    # a photon-counting camera's image, on the electrons' steps, keeps its read noise
    counting = apply_camera_noise(signal, noiseless, np.random.default_rng(7))
    assert with_unresolved_dark_noise(noiseless, counting) is noiseless
    # a measured read noise is kept
    measured = dataclasses.replace(noiseless, dark_noise_e=0.8)
    assert with_unresolved_dark_noise(measured, recording) is measured
    summary = dataclasses.replace(
        estimate_camera(recording, camera=noiseless), camera=drawn
    ).summary()
    assert "dark noise 0.5 e- (too small to measure from this image; the image holds" in summary


def test_summary_of_a_read_noise_too_small_to_measure():
    """Found as a user: diagnose's camera line read "dark noise 0 +- nan e-"."""
    import dataclasses
    import math

    estimate = estimate_camera(
        apply_camera_noise(_smooth_signal(), Camera(), np.random.default_rng(3)), camera=Camera()
    )
    assert "+- nan" not in estimate.summary()
    unmeasured = dataclasses.replace(
        estimate,
        camera=dataclasses.replace(estimate.camera, dark_noise_e=0.0),
        dark_noise_se_e=math.nan,
    )
    assert "dark noise 0 e- (too small to measure from this image)" in unmeasured.summary()
    assert "nan" not in unmeasured.summary()


def test_a_mask_read_as_an_image_is_refused_in_words(real_data_dir):
    """Found as a user: a mask fitted as an image ended with "SVD did not converge in
    Linear Least Squares" in report.txt (noise-free flat levels: zero variance bins)."""
    mask = tifffile.imread(
        real_data_dir / "colicoords/test_data/ds1/binary/00001_Probabilities_filtered.tif"
    )[90:220, 60:320]
    with pytest.raises(ValueError, match="the pixels hold no noise at some grey levels"):
        estimate_camera(mask.astype(float))


def test_a_camera_measured_from_an_8_bit_image_has_8_bits(real_data_dir):
    """Found as a user: the trench saved as an 8-bit PNG was fitted and diagnosed with a
    measured camera of 16 bits, so a dataset matched to it ran past 255 ADU."""
    from napari_symbac.fit import fit_scene
    from napari_symbac.fit.series import _pooled_camera
    from napari_symbac.settings import Microscope, RenderSettings

    real = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff").astype(float)
    scaled = np.rint(255 * (real - real.min()) / np.ptp(real)).astype(np.uint8)
    assert image_bit_depth(scaled) == 8
    assert image_bit_depth(real) == 16
    microscope = Microscope(pixel_size_um=0.065, modality="phase")
    fit = fit_scene(scaled, microscope, RenderSettings(), None, max_iterations=1,
                    irls_rounds=1, moves=False)  # fmt: skip
    assert fit.camera.bit_depth == 8
    assert _pooled_camera(np.stack([scaled, scaled[::-1]])).bit_depth == 8
