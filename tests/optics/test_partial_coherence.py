"""Phase contrast from the condenser annulus and the phase plate: limits and look."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from napari_symbac.optics import ForwardModel
from napari_symbac.optics.partial_coherence import annular_phase_image
from napari_symbac.optics.psf import (
    annulus_transfer_function,
    phase_contrast_kernels,
    phase_contrast_parts,
)
from napari_symbac.scene import scene_from_masks
from napari_symbac.settings import Camera, Microscope, RenderSettings

PX = 0.075  # um, samples the band 2 NA / lambda of NA 1.45 at 0.55 um
OPTICS = {"wavelength_um": 0.55, "numerical_aperture": 1.45, "condenser": "Ph3"}


def _gaussian_blob(n: int, sigma_px: float) -> np.ndarray:
    yy, xx = np.mgrid[:n, :n] - n // 2
    return np.exp(-(yy**2 + xx**2) / (2 * sigma_px**2))


def test_annulus_transfer_function_passes_no_uniform_phase():
    h = annulus_transfer_function(129, PX, 0.55, 1.45, "Ph3")
    assert h[0, 0] == 0.0  # a uniform phase gives no contrast: the shade-off
    assert h.min() >= 0.0
    assert h.max() <= 1.0
    # detail (a quarter of the pupil's radius out) is passed by most source points
    k = round(0.25 * 1.45 / 0.55 * 129 * PX)
    assert h[0, k] > 0.7


@pytest.mark.parametrize("ring_model", ["airy", "annulus"])
def test_kernel_parts_are_normalised(ring_model):
    k_bf, k_ring = phase_contrast_parts(60, PX, 0.55, 1.45, "Ph3", 1.0, ring_model)
    assert k_bf.sum(dtype=np.float64) == pytest.approx(1.0, abs=1e-6)
    assert k_ring.sum(dtype=np.float64) == pytest.approx(0.0, abs=1e-6)
    dc, ring = phase_contrast_kernels(60, PX, 0.55, 1.45, "Ph3", 1.0, 0.1, 0.2)
    assert dc.sum(dtype=np.float64) == pytest.approx(1.0, abs=1e-6)
    assert ring.sum(dtype=np.float64) == pytest.approx(0.0, abs=1e-6)


def test_zero_phase_gives_a_flat_image():
    flat = annular_phase_image(
        np.ones((64, 64)), np.zeros((64, 64)), PX, **OPTICS,
        plate_transmission=0.2, plate_phase_rad=math.pi / 2, apodisation_sigma_um=1.0,
    )  # fmt: skip
    np.testing.assert_allclose(flat, 1.0, atol=1e-12)


@pytest.mark.parametrize("plate_transmission", [0.1, 0.5])
def test_weak_phase_gives_the_linear_annulus_kernel(plate_transmission):
    """First order in phi: ``1 - (2 sin(theta) / sqrt(T)) phi conv h``, h the annulus."""
    n, eps = 128, 1e-3
    phi = eps * _gaussian_blob(n, 5.0)
    image = annular_phase_image(
        np.ones((n, n)), phi, PX, **OPTICS, plate_transmission=plate_transmission,
        plate_phase_rad=math.pi / 2, apodisation_sigma_um=100.0, n_source_points=48,
    )  # fmt: skip
    h = annulus_transfer_function(n, PX, 0.55, 1.45, "Ph3", n_source_points=48)
    linear = np.real(np.fft.ifft2(np.fft.fft2(phi) * h))
    predicted = 1 - 2 / math.sqrt(plate_transmission) * linear
    deviation = image - 1
    assert np.abs(deviation).max() > 1e-3  # there is contrast to compare
    np.testing.assert_allclose(image, predicted, atol=0.01 * np.abs(deviation).max())


def test_defocus_obeys_the_transport_of_intensity_equation_of_the_annulus():
    """Out of focus, bright field of a weak smooth phase bump: ``I(z) - I(-z) =
    -2 z (lambda / 2 pi n) F nabla^2 phi`` to first order in ``z`` (transport of
    intensity), where the annulus' oblique light of angle ``t`` adds
    ``F = (1 + tan^2(t) / 2) / cos(t)`` (the pupil phase expanded to second order in the
    spatial frequency and averaged over the ring's directions), averaged over the two
    source radii the model sums. In focus the bump is invisible."""
    from napari_symbac.settings import CONDENSERS

    n, px, sigma_um, z_um, index = 256, 0.06, 1.2, 0.05, 1.518
    yy, xx = (np.mgrid[:n, :n] - n // 2) * px
    r2 = (yy**2 + xx**2) / sigma_um**2
    phi = 0.05 * np.exp(-r2 / 2)
    laplacian = phi * (r2 - 2) / sigma_um**2
    ring = CONDENSERS["Ph3"]
    centre = 0.5 * (ring.outer_fraction + ring.inner_fraction)
    half = 0.5 * (ring.outer_fraction - ring.inner_fraction)
    factors = []
    for radius in (centre - 0.5 * half, centre + 0.5 * half):
        sine = radius * 1.45 / index
        cosine = math.sqrt(1 - sine**2)
        factors.append((1 + 0.5 * (sine / cosine) ** 2) / cosine)
    bright_field = {"plate_transmission": 1.0, "plate_phase_rad": 0.0, "apodisation_sigma_um": 5.0}
    images = {
        z: annular_phase_image(np.ones((n, n)), phi, px, **OPTICS, **bright_field,
                               focus_offset_um=z, refractive_index=index)
        for z in (-z_um, 0.0, z_um)
    }  # fmt: skip
    predicted = -2 * z_um * 0.55 / (2 * math.pi * index) * np.mean(factors) * laplacian
    difference = images[z_um] - images[-z_um]
    assert difference[n // 2, n // 2] > 0  # a denser bump is a converging lens: focus past it
    np.testing.assert_allclose(difference, predicted, atol=0.03 * np.abs(predicted).max())
    assert np.abs(images[0.0] - 1).max() < 0.01 * np.abs(predicted).max()


def _two_touching_rods(n: int = 160) -> np.ndarray:
    """Two spherocylinders 13 px (~1 um) wide, 80 px long, side by side and touching."""
    yy, xx = np.mgrid[:n, :n] + 0.5
    labels = np.zeros((n, n), np.int64)
    for index, y_centre in enumerate((n / 2 - 6.5, n / 2 + 6.5), start=1):
        along = np.clip(xx, n / 2 - 33.5, n / 2 + 33.5)
        labels[np.hypot(xx - along, yy - y_centre) <= 6.5] = index
    return labels


def test_strong_phase_pair_has_dark_cells_bright_seam_and_halo_above_background():
    microscope = Microscope(pixel_size_um=PX, wavelength_um=0.55)
    render = RenderSettings(
        upsample=1, psf_radius_px=60, cell_intensity=100.0, media_intensity=100.0,
        device_intensity=100.0, apodisation_sigma_um=3.0, phase_model="partially_coherent",
        cell_phase_rad=1.0, plate_transmission=0.15, noise_model="none",
    )  # fmt: skip
    labels = _two_touching_rods()
    scene = scene_from_masks(labels, microscope, render)
    model = ForwardModel(microscope, render, Camera(baseline_adu=0.0))
    image = model.render_clean(scene).astype(np.float64)
    cells = np.median(image[labels > 0])
    halo = np.median(image[64:67, 50:110])  # just above the pair
    background = np.median(image[:20, :20])
    seam = image[79:81, 60:100].mean()  # where the two cells touch
    assert cells < background < halo
    assert halo > background + 0.5 * (background - cells)  # a strong halo
    assert seam > cells + 0.7 * (background - cells)  # a bright line between them
    with pytest.raises(ValueError, match="not a sum of convolved components"):
        model.components(scene)


def test_focus_offset_moves_light_into_the_cells_of_a_phase_colony_and_is_fitted():
    """Out of focus by the pupil's phase, the cells of a strong-phase pair are lighter
    (either way); the pixel fit recovers the focus from an image rendered out of focus."""
    from napari_symbac.fit import fit_parameters

    microscope = Microscope(pixel_size_um=PX, wavelength_um=0.55)
    render = RenderSettings(
        upsample=1, psf_radius_px=60, cell_intensity=100.0, media_intensity=100.0,
        device_intensity=100.0, apodisation_sigma_um=3.0, phase_model="partially_coherent",
        cell_phase_rad=1.0, plate_transmission=0.15, noise_model="gaussian",
        gaussian_noise_sd_adu=1.0, source_points=12,
    )  # fmt: skip
    labels = _two_touching_rods()
    scene = scene_from_masks(labels, microscope, render)
    model = ForwardModel(microscope, render, Camera(baseline_adu=0.0))
    cells = {
        z: np.median(model.with_render(dataclasses.replace(render, focus_offset_um=z))
                     .render_clean(scene)[labels > 0])
        for z in (-0.3, 0.0, 0.3)
    }  # fmt: skip
    assert cells[-0.3] > cells[0.0] + 6  # 0.3 um either way: cells ~12 % of the media lighter
    assert cells[0.3] > cells[0.0] + 6
    truth = dataclasses.replace(render, focus_offset_um=-0.25)
    real = model.with_render(truth).render(scene, np.random.default_rng(1))
    result = fit_parameters(
        real, None, scene, microscope, dataclasses.replace(render, focus_offset_um=-0.1),
        Camera(baseline_adu=0.0), terms=("pixel",), fit=("focus_offset_um",),
        max_evaluations=30, global_search=False,
    )  # fmt: skip
    assert result.render.focus_offset_um == pytest.approx(-0.25, abs=0.02)
    assert result.objective_after < result.objective_before


def test_pupils_kept_inside_their_edge_give_the_image_of_the_whole_pupils():
    """The pupils are computed and applied only within 10 edge widths of their rim, and
    kept for the next frame: the image is that of every frequency through the whole
    soft pupil (the sum of the module's equation), and bit for bit the same when the
    kept pupils are used again, after other optics too."""
    from napari_symbac.optics.partial_coherence import _plate_pupil
    from napari_symbac.settings import CONDENSERS

    rng = np.random.default_rng(3)
    n = 96
    transmission = 0.8 + 0.2 * rng.random((n, n))
    phase = 0.7 * _gaussian_blob(n, 6.0) + 0.3 * rng.random((n, n))
    args = (transmission, phase, PX, 0.55, 1.45, "Ph3", 0.2, math.pi / 2, 0.8)
    image = annular_phase_image(*args, n_source_points=8, focus_offset_um=0.3)
    # the sum written out over the whole frequency plane
    cutoff = 1.45 / 0.55
    fy = np.fft.fftfreq(n, PX)[:, None] / cutoff
    fx = np.fft.fftfreq(n, PX)[None, :] / cutoff
    softness = 1.0 / (2 * math.pi * 0.8 * cutoff)
    ring = CONDENSERS["Ph3"]
    centre = 0.5 * (ring.outer_fraction + ring.inner_fraction)
    half = 0.5 * (ring.outer_fraction - ring.inner_fraction)
    q = math.sqrt(0.2) * complex(0.0, -1.0)
    spectrum = np.fft.fft2(np.sqrt(transmission) * np.exp(1j * phase))
    total, empty = np.zeros((n, n)), 0.0
    for radius in (centre - 0.5 * half, centre + 0.5 * half):
        for angle in np.arange(4) * (math.pi / 2):
            u = np.hypot(fx + radius * math.cos(angle), fy + radius * math.sin(angle))
            pupil = _plate_pupil(u, q, centre - half, centre + half, softness)
            k = u * cutoff
            n_over_lambda = 1.518 / 0.55
            kz = np.sqrt(np.maximum(n_over_lambda**2 - k**2, 0.0))
            pupil = pupil * np.exp(2j * math.pi * 0.3 * (kz - n_over_lambda))
            total += np.abs(np.fft.ifft2(spectrum * pupil)) ** 2
            empty += abs(_plate_pupil(np.array(radius), q, centre - half, centre + half,
                                      softness)) ** 2  # fmt: skip
    np.testing.assert_allclose(image, total / empty, rtol=0, atol=1e-12)
    again = annular_phase_image(*args, n_source_points=8, focus_offset_um=0.3)
    annular_phase_image(*args[:-1], 1.2, n_source_points=8)  # other optics between
    last = annular_phase_image(*args, n_source_points=8, focus_offset_um=0.3)
    assert np.array_equal(image, again)
    assert np.array_equal(image, last)


def test_partially_coherent_empty_scene_renders_the_media_level():
    microscope = Microscope(pixel_size_um=PX, wavelength_um=0.55)
    render = RenderSettings(
        upsample=1, psf_radius_px=20, media_intensity=321.0,
        phase_model="partially_coherent", noise_model="none",
    )  # fmt: skip
    scene = scene_from_masks(np.zeros((32, 40), np.int64), microscope, render)
    image = ForwardModel(microscope, render, Camera(baseline_adu=0.0)).render_clean(scene)
    np.testing.assert_allclose(image, 321.0, rtol=1e-5)
    stages = [s.name for s in ForwardModel(microscope, render).stages]
    assert stages == ["phase_image", "camera"]


def test_undersampled_pupil_is_rejected():
    with pytest.raises(ValueError, match="larger upsample"):
        annular_phase_image(
            np.ones((16, 16)), np.zeros((16, 16)), 0.2, **OPTICS,
            plate_transmission=0.2, plate_phase_rad=1.0, apodisation_sigma_um=1.0,
        )  # fmt: skip


def test_separate_phase_amplitudes_equal_the_coupled_kernel():
    """``cell_phase_adu = gamma (I_m - I_c)`` renders what ``h = k_bf + gamma k_ring`` does."""
    microscope = Microscope(pixel_size_um=PX, wavelength_um=0.55)
    coupled = RenderSettings(
        upsample=1, psf_radius_px=30, cell_intensity=1000.0, media_intensity=2000.0,
        ring_contrast=2.0, ring_model="annulus", noise_model="none",
    )  # fmt: skip
    separate = dataclasses.replace(coupled, cell_phase_adu=2.0 * 1000.0, device_phase_adu=0.0)
    scene = scene_from_masks(_two_touching_rods(96), microscope, coupled)
    a = ForwardModel(microscope, coupled).render_clean(scene)
    b = ForwardModel(microscope, separate).render_clean(scene)
    c = ForwardModel(microscope, separate).render_clean(scene, cache=False)
    assert np.ptp(a) > 100
    np.testing.assert_allclose(b, a, atol=1e-3 * np.ptp(a))
    np.testing.assert_allclose(c, a, atol=1e-3 * np.ptp(a))
