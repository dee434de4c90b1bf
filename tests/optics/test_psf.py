"""PSFs against physics: eq. 6-14 and the 3-D model of section 5."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import fftconvolve

from napari_symbac.optics.psf import (
    airy_psf,
    apodise,
    born_wolf_psf_3d,
    defocus,
    gaussian_kernel,
    phase_contrast_parts,
    phase_contrast_psf,
)
from napari_symbac.settings import CONDENSERS, Microscope

PX = 0.065 / 3


@pytest.mark.parametrize(("wavelength", "na"), [(0.65, 1.45), (0.75, 0.97), (0.52, 0.75)])
def test_airy_first_zero(wavelength, na):
    """The first minimum of the Airy pattern lies at 0.61 lambda / NA (within a pixel)."""
    radius = 40
    psf = airy_psf(radius, PX, wavelength, na)
    profile = psf[radius, radius:]
    first_min = int(np.argmax(np.diff(profile) > 0))  # first index where it rises again
    assert abs(first_min * PX - 0.6098 * wavelength / na) <= PX
    assert psf.sum() == pytest.approx(1.0, abs=1e-6)


def test_kernels_sum_to_one():
    assert gaussian_kernel(20, PX, 0.2).sum() == pytest.approx(1, abs=1e-6)
    for name in CONDENSERS:
        for apo in (0.31, 0.6, 2.0):
            for gamma, offset, dfc in ((0.0, 0.0, 0.0), (1.0, 0.0, 0.1), (3.0, 0.2, 0.3)):
                h = phase_contrast_psf(30, PX, 0.65, 1.45, name, apo, gamma, dfc, offset)
                assert h.dtype == np.float32
                assert h.sum(dtype=np.float64) == pytest.approx(1.0, abs=1e-5)
                k_bf, k_ring = phase_contrast_parts(30, PX, 0.65, 1.45, name, apo)
                assert k_bf.sum(dtype=np.float64) == pytest.approx(1.0, abs=1e-5)
                assert abs(k_ring.sum(dtype=np.float64)) < 1e-5


def test_ring_normalisation_is_not_a_hidden_contrast_knob():
    """Ring part scaled by its own bright-field part: its size stays O(1) for every
    condenser and apodisation (SyMBac's near-cancelling sum inflates it ~800x)."""
    peaks = []
    for name in CONDENSERS:
        for apo in (0.31, 0.6, 1.5):
            k_bf, k_ring = phase_contrast_parts(40, PX, 0.65, 1.45, name, apo)
            peaks.append(np.abs(k_ring).max() / k_bf.max())
    assert max(peaks) < 1.5
    assert max(peaks) / min(peaks) < 10


def test_ring_contrast_gives_bright_halo():
    """Cells darker than media get a bright halo for gamma > 0, none for gamma = 0."""
    n = 301
    yy, xx = np.mgrid[:n, :n]
    disk = np.hypot(yy - n // 2, xx - n // 2) < 25  # a dark object ~1 um across
    image = np.where(disk, 1000.0, 3000.0)
    ring_of_pixels = (np.hypot(yy - n // 2, xx - n // 2) > 25) & (
        np.hypot(yy - n // 2, xx - n // 2) < 45
    )
    for gamma, halo in ((0.0, False), (2.0, True)):
        h = phase_contrast_psf(50, PX, 0.65, 1.45, "Ph3", 0.4, gamma)
        out = fftconvolve(image, h, mode="same")
        peak = out[ring_of_pixels].max()
        if halo:
            assert peak > 3000 * 1.05
        else:
            assert peak < 3000 * 1.01
    # Far from the object the level is unchanged (kernel sum 1).
    assert out[60, 60] == pytest.approx(3000, rel=1e-3)


def test_eq13_lower_bound_enforced():
    mic = Microscope()
    with pytest.raises(ValueError, match=r"eq\. 13"):
        phase_contrast_psf(
            20,
            PX,
            0.65,
            1.45,
            "Ph3",
            0.1,
            0.5,
            min_apodisation_sigma_um=mic.min_apodisation_sigma_um,
        )


def test_apodise_and_defocus():
    psf = airy_psf(40, PX, 0.65, 1.45)
    apod = apodise(psf, PX, 0.2)
    assert apod[40, 40] == psf[40, 40]
    assert apod[40, 0] == pytest.approx(psf[40, 0] * np.exp(-((40 * PX) ** 2) / 0.08), rel=1e-4)
    blurred = defocus(psf, PX, 0.15)
    assert blurred.sum() == pytest.approx(psf.sum(), rel=1e-5)
    r2 = (np.mgrid[-40:41, -40:41] ** 2).sum(0) * PX**2
    # Convolution with a Gaussian adds 2 sigma^2 to the radial second moment.
    m_before = (psf * r2).sum() / psf.sum()
    m_after = (blurred * r2).sum() / blurred.sum()
    assert m_after - m_before == pytest.approx(2 * 0.15**2, rel=0.15)
    np.testing.assert_array_equal(defocus(psf, PX, 0.0), psf)
    with pytest.raises(ValueError, match="odd"):
        apodise(np.ones((4, 4)), PX, 0.2)


def test_born_wolf_focal_plane_is_airy_and_defocus_spreads():
    radius = 30
    z = np.array([-0.6, -0.3, 0.0, 0.3, 0.6])
    psf3 = born_wolf_psf_3d(radius, PX, z, 0.65, 1.3, 1.518)
    assert psf3.shape == (5, 61, 61)
    np.testing.assert_allclose(psf3.sum(axis=(1, 2)), 1.0, atol=1e-5)
    airy = airy_psf(radius, PX, 0.65, 1.3)
    np.testing.assert_allclose(psf3[2], airy, atol=2e-3 * airy.max())
    peaks = psf3[:, radius, radius]
    assert peaks[2] > peaks[1] > peaks[0]
    np.testing.assert_allclose(psf3[1], psf3[3], atol=1e-6)  # symmetric about focus
    with pytest.raises(ValueError, match="exceed"):
        born_wolf_psf_3d(radius, PX, z, 0.65, 1.45, 1.33)


def test_brightfield_kernels_sum_to_one_and_zero():
    from napari_symbac.optics.psf import brightfield_kernels

    k, lens = brightfield_kernels(50, 0.08 / 3, 0.55, 1.4, defocus_sigma_um=0.1)
    assert float(k.sum(dtype=np.float64)) == pytest.approx(1.0, abs=1e-6)
    assert abs(float(lens.sum(dtype=np.float64))) < 1e-5 * float(np.abs(lens).sum())
    assert lens[50, 50] < 0  # the Laplacian of a peak


def test_defocused_weak_phase_obeys_the_transport_of_intensity_equation():
    """The equation the bright-field lens term stands on, checked against free
    propagation: a weak, smooth phase bump (a 1 um wide cell's scale, 0.02 rad) in a
    medium of index n, propagated z = +-0.2 um by the angular spectrum, changes the
    intensity by ``-z lambda / (2 pi n) laplacian(phi)`` to within 3 % of its peak."""
    wavelength, n, px = 0.55, 1.518, 0.02
    size = 256
    coords = (np.arange(size) - size / 2) * px
    yy, xx = np.meshgrid(coords, coords, indexing="ij")
    phi = 0.02 * np.exp(-(xx**2 + yy**2) / (2 * 0.4**2))
    fy, fx = np.meshgrid(np.fft.fftfreq(size, px), np.fft.fftfreq(size, px), indexing="ij")
    kz = np.sqrt(np.maximum((n / wavelength) ** 2 - fx**2 - fy**2, 0.0))
    laplacian = (
        np.roll(phi, 1, 0) + np.roll(phi, -1, 0) + np.roll(phi, 1, 1) + np.roll(phi, -1, 1)
        - 4 * phi
    ) / px**2  # fmt: skip
    for z in (0.2, -0.2):
        field = np.fft.ifft2(np.fft.fft2(np.exp(1j * phi)) * np.exp(2j * np.pi * z * kz))
        change = np.abs(field) ** 2 - 1
        predicted = -z * wavelength / (2 * np.pi * n) * laplacian
        assert np.abs(change - predicted).max() < 0.03 * np.abs(predicted).max()
